//! The methods of Alarms & Conditions: `Acknowledge` and `Confirm` on a robot's condition (an
//! operator's, refused to a reader), and `ConditionRefresh` (anyone signed in), which sends the
//! caller's subscription every retained condition between a `RefreshStartEvent` and a
//! `RefreshEndEvent`.
//!
//! Clients call these with the method ids of the standard types (namespace 0), which the core
//! node manager owns and does not implement. The server routes a call to the first node manager
//! that owns its method id, so this one comes first and owns exactly those ids. Reads of the
//! method nodes themselves (a client browsing the types) go on to the core node manager.

use std::sync::{Arc, Mutex, PoisonError};

use async_trait::async_trait;
use opcua::nodes::{DefaultTypeTree, Event};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::{
    BrowseNode, BrowsePathItem, MethodCall, NodeManager, NodeManagersRef, ReadNode, RequestContext,
    ServerContext,
};
use opcua::types::{
    AttributeId, DateTime, Identifier, MethodId, NodeId, ObjectId, StatusCode, TimestampsToReturn,
    Variant,
};
use ring::rand::{SecureRandom, SystemRandom};
use tracing::{info, warn};

use crate::alarms::Alarm;
use crate::condition_event::{ConditionEvent, parse_condition_id, refresh_event};
use crate::conditions::{ConditionRefusal, ConditionSnapshot, Conditions, Operation};
use crate::manager::ARMTWIN_URI;

/// The methods this node manager answers, by their standard ids.
const METHODS: [MethodId; 4] = [
    MethodId::AcknowledgeableConditionType_Acknowledge,
    MethodId::AcknowledgeableConditionType_Confirm,
    MethodId::ConditionType_ConditionRefresh,
    MethodId::ConditionType_ConditionRefresh2,
];

/// The name of the node manager that owns namespace 0.
const CORE: &str = "core";

/// A fresh event id: random, or zero if the system has no randomness (events then stay
/// distinct by time and source, but a method must name the latest one).
pub(crate) fn event_id(random: &SystemRandom) -> [u8; 16] {
    let mut id = [0_u8; 16];
    let _ = random.fill(&mut id);
    id
}

/// The node manager of the condition methods.
pub(crate) struct ConditionMethods {
    conditions: Arc<Mutex<Conditions>>,
    node_managers: NodeManagersRef,
    random: SystemRandom,
}

impl ConditionMethods {
    pub(crate) fn new(context: &ServerContext, conditions: Arc<Mutex<Conditions>>) -> Self {
        Self {
            conditions,
            node_managers: context.node_managers.clone(),
            random: SystemRandom::new(),
        }
    }

    fn method_of(id: &NodeId) -> Option<MethodId> {
        let method = id.as_method_id().ok()?;
        METHODS.contains(&method).then_some(method)
    }

    /// `Acknowledge` or `Confirm` of the condition `call` names: its new state, or the status
    /// to answer.
    fn act(
        &self,
        context: &RequestContext,
        call: &MethodCall,
        method: MethodId,
    ) -> Result<ConditionSnapshot, StatusCode> {
        let user = context.user_token().0.clone();
        if !context
            .authenticator()
            .is_user_executable(context.user_token(), call.method_id())
        {
            warn!(%user, method = ?method, "OPC UA: a condition method refused to a reader");
            return Err(StatusCode::BadUserAccessDenied);
        }
        let (robot, alarm) = condition_of(context, call.object_id())?;
        let [event, comment] = call.arguments() else {
            return Err(StatusCode::BadArgumentsMissing);
        };
        let Variant::ByteString(acting_on) = event else {
            return Err(StatusCode::BadTypeMismatch);
        };
        let comment = match comment {
            Variant::LocalizedText(text) => text.text.as_ref().to_owned(),
            Variant::Empty => String::new(),
            _ => return Err(StatusCode::BadTypeMismatch),
        };
        let acting_on = acting_on.as_ref();
        let note = (user.as_str(), comment.as_str());
        let id = event_id(&self.random);
        let mut conditions = self
            .conditions
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let operation = if method == MethodId::AcknowledgeableConditionType_Acknowledge {
            Operation::Acknowledge
        } else {
            Operation::Confirm
        };
        conditions
            .operate(
                operation,
                (&robot, alarm),
                acting_on,
                note,
                (DateTime::now(), id),
            )
            .map_err(|refusal| match refusal {
                ConditionRefusal::UnknownCondition => StatusCode::BadNodeIdUnknown,
                ConditionRefusal::UnknownEventId => StatusCode::BadEventIdUnknown,
                ConditionRefusal::AlreadyAcked => StatusCode::BadConditionBranchAlreadyAcked,
                ConditionRefusal::AlreadyConfirmed => {
                    StatusCode::BadConditionBranchAlreadyConfirmed
                }
                ConditionRefusal::NotAcked => StatusCode::BadInvalidState,
            })
    }

    /// `ConditionRefresh`: the retained conditions to the caller's subscription `call` names.
    fn refresh(&self, context: &RequestContext, call: &MethodCall) -> Result<(), StatusCode> {
        let subscription_id = match call.arguments() {
            [Variant::UInt32(id)] | [Variant::UInt32(id), _] => *id,
            [] => return Err(StatusCode::BadArgumentsMissing),
            _ => return Err(StatusCode::BadTypeMismatch),
        };
        let armtwin = armtwin_namespace(context)?;
        let events: Vec<ConditionEvent> = {
            let conditions = self
                .conditions
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            conditions
                .retained()
                .map(|snapshot| ConditionEvent::new(armtwin, snapshot.clone()))
                .collect()
        };
        let start = refresh_event(true, event_id(&self.random));
        let end = refresh_event(false, event_id(&self.random));
        let session = context
            .subscriptions()
            .get_session_subscriptions(context.session_id())
            .ok_or(StatusCode::BadSubscriptionIdInvalid)?;
        let mut session = session.lock();
        let subscription = session
            .get_mut(subscription_id)
            .ok_or(StatusCode::BadSubscriptionIdInvalid)?;
        // The items of the subscription that receive events: on the Server object, which every
        // event reaches, or on a robot's node, which its own conditions reach.
        let items: Vec<(u32, Option<NodeId>)> = subscription
            .items()
            .filter(|item| item.item_to_monitor().attribute_id == AttributeId::EventNotifier)
            .map(|item| {
                let node = &item.item_to_monitor().node_id;
                let source = (node != &ObjectId::Server).then(|| node.clone());
                (item.id(), source)
            })
            .collect();
        let type_tree = context.type_tree().read();
        let type_tree: &DefaultTypeTree = &type_tree;
        for (item, source) in &items {
            subscription.notify_event(item, &start, type_tree);
            for event in &events {
                if source.as_ref().is_none_or(|node| node == event.source()) {
                    subscription.notify_event(item, event as &dyn Event, type_tree);
                }
            }
            subscription.notify_event(item, &end, type_tree);
        }
        info!(
            subscription = subscription_id,
            conditions = events.len(),
            items = items.len(),
            "OPC UA: conditions refreshed"
        );
        Ok(())
    }
}

/// armtwin's namespace index on this server.
fn armtwin_namespace(context: &RequestContext) -> Result<u16, StatusCode> {
    context
        .type_tree()
        .read()
        .namespaces()
        .get_index(ARMTWIN_URI)
        .ok_or(StatusCode::BadInternalError)
}

/// The robot and alarm of the condition node `id`.
fn condition_of(context: &RequestContext, id: &NodeId) -> Result<(String, Alarm), StatusCode> {
    let armtwin = armtwin_namespace(context)?;
    let Identifier::String(text) = &id.identifier else {
        return Err(StatusCode::BadNodeIdUnknown);
    };
    if id.namespace != armtwin {
        return Err(StatusCode::BadNodeIdUnknown);
    }
    let (robot, name) = parse_condition_id(text.as_ref()).ok_or(StatusCode::BadNodeIdUnknown)?;
    let alarm = Alarm::named(name).ok_or(StatusCode::BadNodeIdUnknown)?;
    Ok((robot.to_owned(), alarm))
}

#[async_trait]
impl NodeManager for ConditionMethods {
    fn owns_node(&self, id: &NodeId) -> bool {
        Self::method_of(id).is_some()
    }

    fn name(&self) -> &'static str {
        "armtwin-condition-methods"
    }

    fn namespaces_for_user(&self, _context: &RequestContext) -> Vec<NamespaceMetadata> {
        Vec::new()
    }

    async fn init(&self, _type_tree: &mut DefaultTypeTree, _context: ServerContext) {}

    async fn read(
        &self,
        context: &RequestContext,
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
        nodes_to_read: &mut [&mut ReadNode],
    ) -> Result<(), StatusCode> {
        // The method nodes are the core namespace's: read them there.
        let managers = self
            .node_managers
            .upgrade()
            .ok_or(StatusCode::BadShutdown)?;
        let Some((index, core)) = managers
            .iter()
            .enumerate()
            .find(|(_, manager)| manager.name() == CORE)
        else {
            return Err(StatusCode::BadNodeIdUnknown);
        };
        let mut context = context.clone();
        context.current_node_manager_index = index;
        core.read(&context, max_age, timestamps_to_return, nodes_to_read)
            .await
    }

    async fn browse(
        &self,
        _context: &RequestContext,
        _nodes_to_browse: &mut [BrowseNode],
    ) -> Result<(), StatusCode> {
        // Every node manager sees every browse; the core one answers for the method nodes.
        Ok(())
    }

    async fn translate_browse_paths_to_node_ids(
        &self,
        _context: &RequestContext,
        _nodes: &mut [&mut BrowsePathItem],
    ) -> Result<(), StatusCode> {
        Ok(())
    }

    async fn call(
        &self,
        context: &RequestContext,
        methods_to_call: &mut [&mut MethodCall],
    ) -> Result<(), StatusCode> {
        for call in methods_to_call {
            let Some(method) = Self::method_of(call.method_id()) else {
                continue;
            };
            let outcome = match method {
                MethodId::ConditionType_ConditionRefresh
                | MethodId::ConditionType_ConditionRefresh2 => self.refresh(context, call),
                _ => self.act(context, call, method).map(|snapshot| {
                    let user = snapshot.client_user.clone();
                    let armtwin = armtwin_namespace(context).unwrap_or_default();
                    info!(robot = %snapshot.robot, alarm = snapshot.alarm.name(), %user, acked = snapshot.acked, confirmed = snapshot.confirmed, "OPC UA: condition changed by a client");
                    let event = ConditionEvent::new(armtwin, snapshot);
                    let source = event.source().clone();
                    context
                        .subscriptions()
                        .notify_events([(&event as &dyn Event, &source)].into_iter());
                }),
            };
            call.set_status(match outcome {
                Ok(()) => StatusCode::Good,
                Err(status) => status,
            });
        }
        Ok(())
    }
}
