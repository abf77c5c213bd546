//! The node manager of armtwin's namespace: every twinned robot's nodes, made from the fleet's
//! live state when a request names them and dropped once it is answered, and the robots'
//! variables that clients monitor, sampled at the sampling interval.
//!
//! Keeps nothing per robot but what clients monitor: a robot no client watches costs no byte
//! here, and a sampling turn reads only the robots watched. Knows the fleet only through
//! [`TwinSource`]; the nodes themselves are [`crate::robot`]'s.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use async_trait::async_trait;
use opcua::nodes::{DefaultTypeTree, ReferenceDirection};
use opcua::server::address_space::{AddressSpace, EventNotifier, NodeType, read_node_value};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::{
    AddReferenceResult, BrowseNode, BrowsePathItem, ExternalReference, ExternalReferenceRequest,
    MonitoredItemRef, NodeManager, NodeMetadata, ReadNode, RequestContext, ServerContext,
    WriteNode, impl_translate_browse_paths_using_browse,
};
use opcua::server::{CreateMonitoredItem, MonitoredItemHandle, SubscriptionCache};
use opcua::types::{
    AttributeId, BrowseDirection, DataValue, DateTime, ExpandedNodeId, NodeClass, NodeId,
    ReferenceDescription, ReferenceTypeId, StatusCode, TimestampsToReturn,
};

use crate::manager::{ARMTWIN_URI, DI_URI, Namespaces, ROBOTICS_URI};
use crate::reading::{RobotReading, TwinSource};
use crate::robot::{self, DEVICE_SET, Quantity};

/// The robots' nodes, served from the fleet.
pub(crate) struct RobotNodeManager {
    ns: Namespaces,
    /// The fleet: set once the service starts; no robot before.
    source: OnceLock<Arc<dyn TwinSource>>,
    watched: Mutex<Watched>,
}

/// The robots' variables that clients monitor.
#[derive(Default)]
struct Watched {
    /// Per robot, each monitored variable, what it shows and how many monitored items watch it.
    robots: HashMap<Arc<str>, HashMap<NodeId, (Quantity, usize)>>,
    /// Each monitored item's robot and node.
    items: HashMap<MonitoredItemHandle, (Arc<str>, NodeId)>,
}

/// References found but not yet returned, for `BrowseNext`.
struct ContinuationPoint {
    references: VecDeque<ReferenceDescription>,
}

/// One robot's nodes, made for one request.
struct Scratch {
    space: AddressSpace,
    nodes: robot::RobotNodes,
}

impl RobotNodeManager {
    pub(crate) fn new(context: &ServerContext) -> Self {
        let mut type_tree = context.type_tree.write();
        let namespaces = type_tree.namespaces_mut();
        let ns = Namespaces {
            di: namespaces.add_namespace(DI_URI),
            robotics: namespaces.add_namespace(ROBOTICS_URI),
            armtwin: namespaces.add_namespace(ARMTWIN_URI),
        };
        Self {
            ns,
            source: OnceLock::new(),
            watched: Mutex::new(Watched::default()),
        }
    }

    /// armtwin's namespace's index.
    pub(crate) fn namespace(&self) -> u16 {
        self.ns.armtwin
    }

    /// Serves the robots of `source` from now on.
    pub(crate) fn serve(&self, source: Arc<dyn TwinSource>) {
        let _ = self.source.set(source);
    }

    fn read_robot(&self, id: &str) -> Option<RobotReading> {
        self.source.get()?.read_robot(id)
    }

    /// The robot a node of armtwin's namespace belongs to: its id before `#`.
    fn robot_of(&self, node: &NodeId) -> Option<String> {
        if node.namespace != self.ns.armtwin {
            return None;
        }
        let opcua::types::Identifier::String(id) = &node.identifier else {
            return None;
        };
        let id = id.as_ref();
        Some(id.split_once('#').map_or(id, |(robot, _)| robot).to_owned())
    }

    /// The nodes of `node`'s robot, with their values now, if it is twinned.
    fn scratch_of(&self, node: &NodeId) -> Option<Scratch> {
        let reading = self.read_robot(&self.robot_of(node)?)?;
        Some(self.scratch(&reading))
    }

    fn scratch(&self, reading: &RobotReading) -> Scratch {
        let mut space = AddressSpace::new();
        space.add_namespace(ARMTWIN_URI, self.ns.armtwin);
        let nodes = robot::build(&mut space, self.ns, reading);
        let now = DateTime::now();
        for slot in &nodes.slots {
            if let Some(NodeType::Variable(variable)) = space.find_mut(&slot.node) {
                variable.set_data_value(data_value(slot.quantity.read(reading), now));
            }
        }
        Scratch { space, nodes }
    }

    /// The robots under DI's `DeviceSet`: forward `HasComponent` references to their systems.
    fn browse_device_set(&self, node: &mut BrowseNode, type_tree: &DefaultTypeTree) {
        if !node.allows_forward()
            || !node.allows_reference_type(&ReferenceTypeId::HasComponent.into(), type_tree)
            || !node.allows_node_class(NodeClass::Object)
        {
            return;
        }
        let Some(source) = self.source.get() else {
            return;
        };
        let mut ids = Vec::new();
        source.robot_ids(&mut ids);
        let references = ids.iter().map(|id| ReferenceDescription {
            reference_type_id: ReferenceTypeId::HasComponent.into(),
            is_forward: true,
            node_id: NodeId::new(self.ns.armtwin, id.to_string()).into(),
            browse_name: opcua::types::QualifiedName::new(self.ns.armtwin, id.as_ref()),
            display_name: opcua::types::LocalizedText::new("", id.as_ref()),
            node_class: NodeClass::Object,
            type_definition: NodeId::new(self.ns.robotics, robot::MOTION_DEVICE_SYSTEM_TYPE).into(),
        });
        add_references(node, type_tree, references);
    }

    /// A node of a robot: its references in the robot's scratch nodes; those leaving them
    /// (types, `DeviceSet`) resolved by the node managers that own their targets.
    fn browse_robot_node(node: &mut BrowseNode, type_tree: &DefaultTypeTree, scratch: &Scratch) {
        let filter = if node.reference_type_id().is_null() {
            None
        } else {
            node.reference_type_id()
                .as_reference_type_id()
                .ok()
                .map(|id| (id, node.include_subtypes()))
        };
        let source = node.node_id().clone();
        let space = &scratch.space;
        let mut found = Vec::new();
        for reference in space.find_references(&source, filter, type_tree, node.browse_direction())
        {
            let Some(target) = space.find_node(reference.target_node) else {
                node.push_external_reference(ExternalReference::new(
                    reference.target_node.clone().into(),
                    reference.reference_type.clone(),
                    reference.direction,
                ));
                continue;
            };
            let target = target.as_node();
            let type_definition = match target.node_class() {
                NodeClass::Object | NodeClass::Variable => space
                    .find_references(
                        target.node_id(),
                        Some((ReferenceTypeId::HasTypeDefinition, false)),
                        type_tree,
                        BrowseDirection::Forward,
                    )
                    .next()
                    .map_or_else(ExpandedNodeId::null, |t| t.target_node.clone().into()),
                _ => ExpandedNodeId::null(),
            };
            let description = ReferenceDescription {
                reference_type_id: reference.reference_type.clone(),
                is_forward: matches!(reference.direction, ReferenceDirection::Forward),
                node_id: target.node_id().clone().into(),
                browse_name: target.browse_name().clone(),
                display_name: target.display_name().clone(),
                node_class: target.node_class(),
                type_definition,
            };
            found.push(description);
        }
        add_references(node, type_tree, found);
    }

    /// One sampling turn: each monitored variable's value now, to the monitored items watching
    /// it. Reads the robots watched, one lock each, and no other.
    pub(crate) fn sample(&self, subscriptions: &SubscriptionCache) {
        let Some(source) = self.source.get() else {
            return;
        };
        let watched = self.watched.lock().unwrap_or_else(PoisonError::into_inner);
        if watched.robots.is_empty() {
            return;
        }
        let now = DateTime::now();
        let mut notifier = subscriptions.data_notifier();
        for (robot, variables) in &watched.robots {
            // A robot retired while watched: its items hear nothing until it is twinned again.
            let Some(reading) = source.read_robot(robot) else {
                continue;
            };
            for (node, (quantity, _)) in variables {
                if let Some(mut batch) = notifier.notify_for(node, AttributeId::Value) {
                    batch.data_value(data_value(quantity.read(&reading), now));
                }
            }
        }
    }

    /// How many variables clients monitor, over how many robots.
    pub(crate) fn watched(&self) -> (usize, usize) {
        let watched = self.watched.lock().unwrap_or_else(PoisonError::into_inner);
        (
            watched.robots.values().map(HashMap::len).sum(),
            watched.robots.len(),
        )
    }

    fn watch(&self, handle: MonitoredItemHandle, robot: &str, node: &NodeId, quantity: Quantity) {
        let mut watched = self.watched.lock().unwrap_or_else(PoisonError::into_inner);
        let robot: Arc<str> = watched
            .robots
            .get_key_value(robot)
            .map_or_else(|| Arc::from(robot), |(known, _)| Arc::clone(known));
        watched
            .robots
            .entry(Arc::clone(&robot))
            .or_default()
            .entry(node.clone())
            .or_insert((quantity, 0))
            .1 += 1;
        watched.items.insert(handle, (robot, node.clone()));
    }

    fn unwatch(&self, handle: MonitoredItemHandle) {
        let mut watched = self.watched.lock().unwrap_or_else(PoisonError::into_inner);
        let Some((robot, node)) = watched.items.remove(&handle) else {
            return;
        };
        let Some(variables) = watched.robots.get_mut(&robot) else {
            return;
        };
        if let Some((_, count)) = variables.get_mut(&node) {
            *count -= 1;
            if *count == 0 {
                variables.remove(&node);
            }
        }
        if variables.is_empty() {
            watched.robots.remove(&robot);
        }
    }
}

/// Adds `references` to `node`'s result; those past what it may return wait for `BrowseNext`.
fn add_references(
    node: &mut BrowseNode,
    type_tree: &DefaultTypeTree,
    references: impl IntoIterator<Item = ReferenceDescription>,
) {
    let mut rest = VecDeque::new();
    for reference in references {
        if let AddReferenceResult::Full(reference) = node.add(type_tree, reference) {
            rest.push_back(reference);
        }
    }
    if !rest.is_empty() {
        node.set_next_continuation_point(Box::new(ContinuationPoint { references: rest }));
    }
}

/// A variable's value as sampled at `now`.
fn data_value((value, status): robot::Reading, now: DateTime) -> DataValue {
    DataValue {
        value: Some(value),
        status: Some(status),
        source_timestamp: Some(now),
        server_timestamp: Some(now),
        ..DataValue::default()
    }
}

/// Scratch nodes per robot named in one request, each made once.
struct Scratches<'a> {
    manager: &'a RobotNodeManager,
    made: HashMap<String, Option<Scratch>>,
}

impl<'a> Scratches<'a> {
    fn new(manager: &'a RobotNodeManager) -> Self {
        Self {
            manager,
            made: HashMap::new(),
        }
    }

    fn of(&mut self, node: &NodeId) -> Option<&Scratch> {
        let robot = self.manager.robot_of(node)?;
        self.made
            .entry(robot)
            .or_insert_with(|| self.manager.scratch_of(node))
            .as_ref()
    }
}

#[async_trait]
impl NodeManager for RobotNodeManager {
    fn owns_node(&self, id: &NodeId) -> bool {
        id.namespace == self.ns.armtwin
    }

    fn name(&self) -> &'static str {
        "armtwin-robots"
    }

    fn namespaces_for_user(&self, _context: &RequestContext) -> Vec<NamespaceMetadata> {
        vec![NamespaceMetadata {
            namespace_uri: ARMTWIN_URI.to_owned(),
            namespace_index: self.ns.armtwin,
            ..NamespaceMetadata::default()
        }]
    }

    async fn init(&self, _type_tree: &mut DefaultTypeTree, _context: ServerContext) {}

    async fn resolve_external_references(
        &self,
        _context: &RequestContext,
        items: &mut [&mut ExternalReferenceRequest],
    ) {
        let mut scratches = Scratches::new(self);
        for item in items {
            let id = item.node_id().clone();
            let Some(scratch) = scratches.of(&id) else {
                continue;
            };
            let Some(node) = scratch.space.find_node(&id) else {
                continue;
            };
            let node = node.as_node();
            item.set(NodeMetadata {
                node_id: id.clone().into(),
                type_definition: ExpandedNodeId::null(),
                browse_name: node.browse_name().clone(),
                display_name: node.display_name().clone(),
                node_class: node.node_class(),
            });
        }
    }

    async fn browse(
        &self,
        context: &RequestContext,
        nodes_to_browse: &mut [BrowseNode],
    ) -> Result<(), StatusCode> {
        let device_set = NodeId::new(self.ns.di, DEVICE_SET);
        let mut scratches = Scratches::new(self);
        let type_tree = context.type_tree.read();
        for node in nodes_to_browse.iter_mut() {
            if let Some(mut point) = node.take_continuation_point::<ContinuationPoint>() {
                while node.remaining() > 0 {
                    let Some(reference) = point.references.pop_front() else {
                        break;
                    };
                    node.add_unchecked(reference);
                }
                if !point.references.is_empty() {
                    node.set_next_continuation_point(point);
                }
                continue;
            }
            if node.node_id() == &device_set {
                self.browse_device_set(node, &type_tree);
            } else if self.owns_node(node.node_id()) {
                let id = node.node_id().clone();
                match scratches.of(&id) {
                    Some(scratch) if scratch.space.find_node(&id).is_some() => {
                        node.set_status(StatusCode::Good);
                        Self::browse_robot_node(node, &type_tree, scratch);
                    }
                    _ => node.set_status(StatusCode::BadNodeIdUnknown),
                }
            }
        }
        Ok(())
    }

    async fn translate_browse_paths_to_node_ids(
        &self,
        context: &RequestContext,
        nodes: &mut [&mut BrowsePathItem],
    ) -> Result<(), StatusCode> {
        impl_translate_browse_paths_using_browse(self, context, nodes).await
    }

    async fn read(
        &self,
        context: &RequestContext,
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
        nodes_to_read: &mut [&mut ReadNode],
    ) -> Result<(), StatusCode> {
        let mut scratches = Scratches::new(self);
        for node in nodes_to_read {
            let id = node.node().node_id.clone();
            let value = match scratches.of(&id) {
                Some(scratch) => {
                    scratch
                        .space
                        .read(context, node.node(), max_age, timestamps_to_return)
                }
                None => DataValue {
                    status: Some(StatusCode::BadNodeIdUnknown),
                    ..DataValue::default()
                },
            };
            node.set_result(value);
        }
        Ok(())
    }

    async fn write(
        &self,
        _context: &RequestContext,
        nodes_to_write: &mut [&mut WriteNode],
    ) -> Result<(), StatusCode> {
        // A twin is changed through the admin keys behind the ACL, never through OPC UA.
        for node in nodes_to_write {
            node.set_status(StatusCode::BadNotWritable);
        }
        Ok(())
    }

    async fn create_monitored_items(
        &self,
        context: &RequestContext,
        items: &mut [&mut CreateMonitoredItem],
    ) -> Result<(), StatusCode> {
        let mut scratches = Scratches::new(self);
        for item in items {
            let id = item.item_to_monitor().node_id.clone();
            let Some(scratch) = scratches.of(&id) else {
                item.set_status(StatusCode::BadNodeIdUnknown);
                continue;
            };
            let node = match scratch
                .space
                .validate_node_read(context, item.item_to_monitor())
            {
                Ok(node) => node,
                Err(status) => {
                    item.set_status(status);
                    continue;
                }
            };
            let value = read_node_value(
                node,
                context,
                item.item_to_monitor(),
                0.0,
                item.timestamps_to_return(),
            );
            match item.item_to_monitor().attribute_id {
                // Events are global: the node need only let clients subscribe to them.
                AttributeId::EventNotifier => {
                    let notifies = matches!(
                        value.value,
                        Some(opcua::types::Variant::Byte(bits))
                            if EventNotifier::from_bits_truncate(bits)
                                .contains(EventNotifier::SUBSCRIBE_TO_EVENTS)
                    );
                    item.set_status(if notifies {
                        StatusCode::Good
                    } else {
                        StatusCode::BadAttributeIdInvalid
                    });
                    continue;
                }
                AttributeId::Value => {
                    if let Some(slot) = scratch.nodes.slots.iter().find(|slot| slot.node == id)
                        && let Some(robot) = self.robot_of(&id)
                    {
                        self.watch(item.handle(), &robot, &id, slot.quantity);
                    }
                }
                _ => {}
            }
            if value.status() != StatusCode::BadAttributeIdInvalid {
                item.set_initial_value(value);
            }
            item.set_status(StatusCode::Good);
        }
        Ok(())
    }

    async fn delete_monitored_items(&self, _context: &RequestContext, items: &[&MonitoredItemRef]) {
        for item in items {
            self.unwatch(item.handle());
        }
    }
}
