//! Why the service stopped with an error.
//!
//! Must not know any other part of the service: every part may fail with it.

use thiserror::Error;

use armtwin_mesh::MeshError;

/// Why the service stopped with an error.
#[derive(Debug, Error)]
pub enum ServiceError {
    /// The Zenoh configuration is invalid.
    #[error("zenoh configuration: {0}")]
    ZenohConfig(String),
    /// Zenoh failed (opening the session, declaring, …).
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// The control thread failed.
    #[error("control thread: {0}")]
    Worker(String),
    /// Another instance on the mesh already owns some of this instance's robots.
    #[error(
        "service.robots '{own}' overlaps '{other}', owned by the armtwin instance {zid}: a robot \
         must belong to one instance (give each a disjoint key expression)"
    )]
    ShardOverlap {
        /// This instance's `[service] robots`.
        own: String,
        /// The other instance's.
        other: String,
        /// The other instance's Zenoh id.
        zid: String,
    },
    /// The dashboard's address cannot be listened on.
    #[error("http: cannot listen on {address}")]
    HttpListen {
        /// The `[http] listen` address.
        address: std::net::SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// `[http] listen` is set, but the service was started without an HTTP side to serve it.
    #[error(
        "http: [http] listen is set, but this build of the service has no HTTP side to serve it"
    )]
    NoHttpDoor,
    /// The OPC UA server could not start (`[opcua]`).
    #[error("{0}")]
    OpcUa(String),
}

/// The OPC UA server could not start.
impl From<armtwin_opcua::OpcUaError> for ServiceError {
    fn from(error: armtwin_opcua::OpcUaError) -> Self {
        Self::OpcUa(error.to_string())
    }
}

impl From<MeshError> for ServiceError {
    fn from(error: MeshError) -> Self {
        match error {
            MeshError::Config(message) => Self::ZenohConfig(message),
            MeshError::Zenoh(error) => Self::Zenoh(error),
        }
    }
}
