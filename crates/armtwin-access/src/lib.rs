//! Who may do what on armtwin's doors.
//!
//! - [`acl`]: a fleet description (`fleet.toml`: who speaks for which robots) as a Zenoh router's
//!   access control and TLS settings.
//! - [`certs`]: a fleet's certificates by role: its CA, the router's, a client's per name.
//! - [`http_access`]: the dashboard's TLS identity, its tokens and their roles.
//!
//! Must not serve anything: the router enforces the ACL, the dashboard checks the tokens.

pub mod acl;
pub mod certs;
pub mod http_access;
