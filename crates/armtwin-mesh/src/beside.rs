//! Work a process runs on the service's own session, beside the twin: the UR controllers `serve`
//! streams itself (`[robots."<id>"] rtde`). The service starts it once it takes input and stops
//! it before it stops taking input, and knows it through these traits alone, so that it does
//! not depend on what the work is.

use std::future::Future;
use std::pin::Pin;

use zenoh::Session;

use crate::keys::KeySpace;

/// Work to start on the service's session.
pub trait Beside: Send {
    /// Starts on `session`, whose keys are `keys`; runs until [`Running::stop`].
    fn start(self: Box<Self>, session: Session, keys: KeySpace) -> Box<dyn Running>;
}

/// Work [`Beside::start`] started.
pub trait Running: Send {
    /// Ends it, bounded in time: what it declared on the session is undeclared by then.
    fn stop(self: Box<Self>) -> Pin<Box<dyn Future<Output = ()> + Send>>;
}
