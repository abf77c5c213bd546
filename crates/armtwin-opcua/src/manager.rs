//! The node manager of the information models: DI and Robotics, imported from the OPC
//! Foundation's `NodeSet2` files into memory once, and armtwin's namespace reserved after them.
//! Read-only: every write is refused.
//!
//! Must not know a robot: [`crate::robots`] serves their nodes, in armtwin's namespace.

use async_trait::async_trait;
use opcua::nodes::NodeSet2Import;
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{InMemoryNodeManagerBuilder, InMemoryNodeManagerImpl};
use opcua::server::node_manager::{RequestContext, ServerContext, WriteNode};
use opcua::sync::RwLock;
use opcua::types::StatusCode;
use tracing::info;

/// OPC 10000-100 (Devices), as published.
const DI_NODESET: &str = include_str!("../nodesets/Opc.Ua.Di.NodeSet2.xml");
/// OPC 40010-1 (Robotics), as published.
const ROBOTICS_NODESET: &str = include_str!("../nodesets/Opc.Ua.Robotics.NodeSet2.xml");

/// The DI namespace's URI.
pub(crate) const DI_URI: &str = "http://opcfoundation.org/UA/DI/";
/// The Robotics namespace's URI.
pub(crate) const ROBOTICS_URI: &str = "http://opcfoundation.org/UA/Robotics/";
/// armtwin's namespace: the robots' instance nodes and armtwin's own variables.
pub(crate) const ARMTWIN_URI: &str = "urn:armtwin:opcua";

/// The namespaces' indices on this server.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Namespaces {
    pub(crate) di: u16,
    pub(crate) robotics: u16,
    pub(crate) armtwin: u16,
}

/// What the models' node manager does beyond the in-memory default: its namespaces, and no
/// writes.
pub(crate) struct ModelNodes {
    namespaces: Vec<NamespaceMetadata>,
}

/// Why the information models could not be read (a build with broken `NodeSet` files).
#[derive(Debug, thiserror::Error)]
#[error("the {name} NodeSet cannot be read: {problem}")]
pub struct NodeSetError {
    name: &'static str,
    problem: String,
}

/// The two `NodeSet`s parsed, checked before the server is built (whose builder cannot fail).
pub(crate) fn parse_nodesets() -> Result<[NodeSet2Import; 2], NodeSetError> {
    let parse = |name: &'static str, text: &str| {
        NodeSet2Import::new_str("en", text, Vec::new()).map_err(|e| NodeSetError {
            name,
            problem: e.to_string(),
        })
    };
    Ok([
        parse("DI", DI_NODESET)?,
        parse("Robotics", ROBOTICS_NODESET)?,
    ])
}

/// The models' node manager's builder: imports `nodesets` (DI first, which Robotics needs) and
/// gives armtwin's namespace its index after theirs, for [`crate::robots`] to serve.
pub(crate) fn builder(
    nodesets: [NodeSet2Import; 2],
) -> InMemoryNodeManagerBuilder<impl FnOnce(ServerContext, &mut AddressSpace) -> ModelNodes> {
    InMemoryNodeManagerBuilder::new(
        move |context: ServerContext, address_space: &mut AddressSpace| {
            let mut type_tree = context.type_tree.write();
            let mut namespaces = Vec::new();
            for import in &nodesets {
                address_space.import_node_set(import, type_tree.namespaces_mut());
            }
            for uri in [DI_URI, ROBOTICS_URI] {
                let namespace_index = type_tree.namespaces_mut().add_namespace(uri);
                address_space.add_namespace(uri, namespace_index);
                namespaces.push(NamespaceMetadata {
                    namespace_uri: uri.to_owned(),
                    namespace_index,
                    ..NamespaceMetadata::default()
                });
            }
            type_tree.namespaces_mut().add_namespace(ARMTWIN_URI);
            info!(
                namespaces = ?namespaces.iter().map(|n| (n.namespace_index, &n.namespace_uri)).collect::<Vec<_>>(),
                "OPC UA: DI and Robotics information models imported"
            );
            ModelNodes { namespaces }
        },
    )
}

#[async_trait]
impl InMemoryNodeManagerImpl for ModelNodes {
    async fn init(&self, _address_space: &mut AddressSpace, _context: ServerContext) {}

    fn name(&self) -> &'static str {
        "armtwin-models"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        self.namespaces.clone()
    }

    async fn write(
        &self,
        _context: &RequestContext,
        _address_space: &RwLock<AddressSpace>,
        nodes_to_write: &mut [&mut WriteNode],
    ) -> Result<(), StatusCode> {
        // A twin is changed through the admin keys behind the ACL, never through OPC UA.
        for node in nodes_to_write {
            node.set_status(StatusCode::BadNotWritable);
        }
        Ok(())
    }
}
