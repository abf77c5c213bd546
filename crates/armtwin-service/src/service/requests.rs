//! What the rest of the service asks of the control thread: declare a newly tracked robot's
//! liveliness token, declare the route caches of a robot that streams, stop.
//!
//! Must not wait: a request is queued, and one made after the control thread stopped is dropped
//! (nothing is declared any more by then).

use std::sync::mpsc::{Receiver, Sender, channel};

use armtwin_core::pipeline::Robot;

/// A request to the control thread.
pub(super) enum Request {
    /// Declare a newly tracked robot's liveliness token.
    Track(Robot),
    /// Declare the publishers and input keys that cache a streaming robot's routes.
    CacheRoutes(Robot),
    /// Finish the pipeline, undeclare everything and stop.
    Stop,
}

/// The control thread's queue, as the rest of the service holds it.
#[derive(Clone)]
pub(super) struct Requests {
    queue: Sender<Request>,
}

/// A queue of requests, and the control thread's end of it.
pub(super) fn queue() -> (Requests, Receiver<Request>) {
    let (queue, received) = channel();
    (Requests { queue }, received)
}

impl Requests {
    /// Asks for `robot`'s liveliness token: it is tracked now.
    pub(super) fn track(&self, robot: &Robot) {
        self.send(Request::Track(robot.clone()));
    }

    /// Asks for `robot`'s route caches: it streams at the rate that repays them.
    pub(super) fn cache_routes(&self, robot: &Robot) {
        self.send(Request::CacheRoutes(robot.clone()));
    }

    /// Asks the control thread to finish every twin and stop.
    pub(super) fn stop(&self) {
        self.send(Request::Stop);
    }

    fn send(&self, request: Request) {
        // Fails only once the control thread has stopped, when nothing is declared any more.
        let _ = self.queue.send(request);
    }
}
