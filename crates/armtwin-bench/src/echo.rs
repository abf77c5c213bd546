//! `armtwin-bench echo`: the best plain-Zenoh echo of armtwin's message pattern, the baseline
//! every armtwin figure is divided by.
//!
//! One wildcard subscriber per input stream republishes each payload unchanged with its encoding
//! (a JSON and a Zenoh-serialized load cost it the same, so it needs no encoding flag), straight
//! from Zenoh's receive callback (no queue, no thread hop, no decoding), through a publisher
//! declared up front per robot: `joints/<robot>` → `pose/<robot>`, `measured/<robot>` → `deviation/<robot>`.
//! `--paired` answers armtwin's paired output (`[service] outputs = "paired"`: one message per
//! paired sample): `joints/<robot>` → `paired/<robot>`, and measured poses are received but not
//! republished, so both systems take the same messages in and send one per sample out (the echo's
//! reply does not wait for the measured message, armtwin's does: the latencies favour the echo).
//! Each robot's input keys are declared (`declare_keyexpr`) so Zenoh caches their routes, as
//! armtwin does for a robot that streams; `--naive` leaves them undeclared to measure what that costs. `--lazy` meets
//! the robots on first contact: nothing is declared per robot up front, and a robot's publisher
//! is declared in the receive callback on its first sample (the baseline of a system that is not
//! told its fleet in advance).
//!
//! Runs until its standard input closes (or it is killed); prints `ready` once declared.

use std::collections::HashMap;
use std::io::{Read, Write};
use std::sync::{Arc, PoisonError, RwLock};

use armtwin_cli::flags::ZenohArgs;
use armtwin_mesh::MeshError;
use armtwin_mesh::keys::Stream;
use clap::Args;
use thiserror::Error;
use zenoh::Wait;
use zenoh::key_expr::KeyExpr;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;
use zenoh::session::Session;

use crate::net;

/// `armtwin-bench echo` arguments.
#[derive(Debug, Args)]
#[command(mut_arg("listen", |arg| arg.required(true)))]
pub struct EchoArgs {
    /// How to join the mesh, as armtwin's commands do (`-l ENDPOINT` required).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    /// Robots to declare publishers for (`fleet/r00000` …).
    #[arg(long, default_value_t = 1)]
    pub robots: usize,
    /// Do not declare the robots' input keys, so Zenoh resolves each received key anew (the
    /// baseline for what declaring them saves).
    #[arg(long)]
    pub naive: bool,
    /// Declare nothing per robot up front: a robot's publisher is declared on its first sample,
    /// in the receive callback.
    #[arg(long)]
    pub lazy: bool,
    /// One message out per sample, as armtwin's paired output: joint samples republished on
    /// `paired/<robot>`, measured poses received and dropped.
    #[arg(long)]
    pub paired: bool,
}

/// Why the echo stopped with an error.
#[derive(Debug, Error)]
pub enum EchoError {
    /// The Zenoh configuration was refused.
    #[error(transparent)]
    Config(#[from] MeshError),
    /// Zenoh failed.
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
    /// Standard input or output failed.
    #[error("stdio: {0}")]
    Io(#[from] std::io::Error),
}

/// Publishers of one output stream, by robot id.
type Routes = HashMap<Box<str>, Publisher<'static>>;

fn routes(session: &Session, robots: usize, output: Stream) -> Result<Routes, zenoh::Error> {
    (0..robots)
        .map(|index| {
            let robot = net::robot_id(index);
            let publisher = session
                .declare_publisher(net::key(output, &robot))
                .congestion_control(CongestionControl::Block)
                .wait()?;
            Ok((robot.into_boxed_str(), publisher))
        })
        .collect()
}

/// Republishes `sample`'s payload on its robot's publisher of `routes`.
fn forward(routes: &Routes, input: Stream, sample: &Sample) {
    let robot = net::robot_of(sample.key_expr().as_str(), input);
    if let Some(publisher) = robot.and_then(|robot| routes.get(robot)) {
        // Only fails when the session is closing.
        let _ = publisher
            .put(sample.payload().clone())
            .encoding(sample.encoding().clone())
            .wait();
    }
}

/// The publishers of one output stream, declared on each robot's first sample.
struct LazyRoutes {
    session: Session,
    output: Stream,
    routes: RwLock<Routes>,
}

impl LazyRoutes {
    /// Republishes `sample`'s payload on its robot's publisher, declaring it first if this is
    /// the robot's first sample. The read lock is shared by every receiving thread; the write
    /// lock is taken once per robot.
    fn forward(&self, input: Stream, sample: &Sample) {
        let Some(robot) = net::robot_of(sample.key_expr().as_str(), input) else {
            return;
        };
        let routes = self.routes.read().unwrap_or_else(PoisonError::into_inner);
        if let Some(publisher) = routes.get(robot) {
            let _ = publisher
                .put(sample.payload().clone())
                .encoding(sample.encoding().clone())
                .wait();
            return;
        }
        drop(routes);
        let mut routes = self.routes.write().unwrap_or_else(PoisonError::into_inner);
        if !routes.contains_key(robot) {
            // Only fails when the session is closing; the sample is then dropped.
            let Ok(publisher) = self
                .session
                .declare_publisher(net::key(self.output, robot))
                .congestion_control(CongestionControl::Block)
                .wait()
            else {
                return;
            };
            routes.insert(robot.into(), publisher);
        }
        if let Some(publisher) = routes.get(robot) {
            let _ = publisher
                .put(sample.payload().clone())
                .encoding(sample.encoding().clone())
                .wait();
        }
    }
}

/// Runs the echo until standard input closes.
pub fn run(args: &EchoArgs) -> Result<(), EchoError> {
    let session = zenoh::open(net::config_of(&args.zenoh)?).wait()?;
    let mut declared: Vec<KeyExpr<'static>> = Vec::new();
    if !args.naive && !args.lazy {
        for index in 0..args.robots {
            let robot = net::robot_id(index);
            for input in [net::JOINTS, net::MEASURED] {
                declared.push(session.declare_keyexpr(net::key(input, &robot)).wait()?);
            }
        }
    }
    let mut subscribers = Vec::new();
    let outputs = if args.paired {
        [(net::JOINTS, Some(net::PAIRED)), (net::MEASURED, None)]
    } else {
        [
            (net::JOINTS, Some(net::POSE)),
            (net::MEASURED, Some(net::DEVIATION)),
        ]
    };
    for (input, output) in outputs {
        let Some(output) = output else {
            // Received as armtwin receives it, answered by nothing.
            subscribers.push(
                session
                    .declare_subscriber(net::every_robot(input))
                    .callback(|_| {})
                    .wait()?,
            );
            continue;
        };
        if args.lazy {
            let routes = Arc::new(LazyRoutes {
                session: session.clone(),
                output,
                routes: RwLock::new(Routes::new()),
            });
            subscribers.push(
                session
                    .declare_subscriber(net::every_robot(input))
                    .callback(move |sample| routes.forward(input, &sample))
                    .wait()?,
            );
            continue;
        }
        let routes = Arc::new(routes(&session, args.robots, output)?);
        subscribers.push(
            session
                .declare_subscriber(net::every_robot(input))
                .callback(move |sample| forward(&routes, input, &sample))
                .wait()?,
        );
    }
    let mut stdout = std::io::stdout();
    writeln!(stdout, "ready")?;
    stdout.flush()?;
    // Until the orchestrator closes our standard input.
    std::io::stdin().read_to_end(&mut Vec::new())?;
    drop(subscribers);
    drop(declared);
    session.close().wait()?;
    Ok(())
}
