//! `armtwin gateway rtde`: Universal Robots controllers streamed into the mesh over RTDE, one TCP
//! connection per controller and one Zenoh session for all of them. Each data package becomes
//! a joint message (`armtwin/joints/v2`) on the robot's joints key, with the controller's
//! `actual_TCP_pose` embedded as its measured pose; what the gateway reads of the controller
//! beside (its `tcp_offset`, and its model and serial number from the dashboard server) goes on
//! the robot's controller key ([`armtwin_mesh::controller`]) when it changes.
//!
//! - [`clock`]: stamps from the controller's clock, offset to wall time once per connection.
//! - [`dashboard`]: the controller's dashboard server, read for its model and serial number.
//! - `link`: one controller's connection, reconnection and publishing.
//!
//! The same links run inside `serve` on the service's own session ([`InService`], for
//! `[robots."<id>"] rtde = "ADDRESS"`).
//!
//! Owns the fleet's settings (a fleet file, `gateways.toml`) and the session's lifetime; must
//! not parse RTDE bytes (the codec's `rtde` module does).

pub mod clock;
pub mod dashboard;
mod link;

pub use link::{LinkError, probe};

use std::collections::HashSet;
use std::future::Future;
use std::path::PathBuf;
use std::pin::Pin;

use serde::Deserialize;
use thiserror::Error;
use tokio::sync::watch;
use tracing::info;
use zenoh::Session;

use armtwin_codec::rtde::DEFAULT_PORT;
use armtwin_mesh::beside::{Beside, Running};
use armtwin_mesh::keys::{self, KeySpace, PlainKeyError, Stream};
use armtwin_mesh::zenoh_section::ZenohSection;
use armtwin_mesh::{
    MeshError, TEARDOWN_STEP, aggregate_publishers, bounded, close_session, zenoh_config_of,
};

/// The output frequency asked for unless one is given: an e-Series controller's rate (a CB3
/// streams at most 125 Hz and says so by refusing more).
pub const DEFAULT_FREQUENCY_HZ: f64 = 500.0;

/// One controller to stream.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerSettings {
    /// The robot id it is published as.
    pub robot: String,
    /// The controller's address.
    pub host: String,
    /// Its RTDE port.
    #[serde(default = "default_port")]
    pub port: u16,
    /// Its dashboard server's port.
    #[serde(default = "default_dashboard_port")]
    pub dashboard_port: u16,
    /// The output frequency to ask for (Hz).
    #[serde(default = "default_frequency_hz", rename = "frequency")]
    pub frequency_hz: f64,
    /// Also write every data package to this CSV (`ur_rtde`'s form), appended to an earlier
    /// run's of the same columns.
    #[serde(default)]
    pub record: Option<PathBuf>,
}

fn default_port() -> u16 {
    DEFAULT_PORT
}

fn default_dashboard_port() -> u16 {
    dashboard::DEFAULT_PORT
}

fn default_frequency_hz() -> f64 {
    DEFAULT_FREQUENCY_HZ
}

/// A fleet file: `[[controllers]]` entries and, optionally, the key prefix.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FleetFile {
    #[serde(default)]
    key_prefix: Option<String>,
    controllers: Vec<ControllerSettings>,
}

/// The gateway's settings.
#[derive(Debug, Clone)]
pub struct GatewaySettings {
    /// How to join the mesh.
    pub zenoh: ZenohSection,
    /// Key prefix of the service (`twin`).
    pub key_prefix: String,
    /// The controllers.
    pub controllers: Vec<ControllerSettings>,
}

/// Why the gateway cannot run (nothing a controller does ends it).
#[derive(Debug, Error)]
pub enum GatewayError {
    /// The fleet file does not parse.
    #[error("{source_name}: {message}")]
    FleetFile {
        /// The file.
        source_name: String,
        /// What is wrong.
        message: String,
    },
    /// A robot id or the prefix is not a plain key.
    #[error("'{text}' {problem}")]
    Key {
        /// The id or prefix.
        text: String,
        /// What is wrong with it.
        problem: PlainKeyError,
    },
    /// Two controllers publish as one robot.
    #[error("robot '{robot}' is named by two controllers")]
    DuplicateRobot {
        /// The robot id.
        robot: String,
    },
    /// A frequency outside (0, 500] Hz.
    #[error("robot '{robot}': frequency {frequency_hz} Hz is not within (0, 500]")]
    Frequency {
        /// The robot id.
        robot: String,
        /// The frequency.
        frequency_hz: f64,
    },
    /// No controller to stream.
    #[error("no controller to stream")]
    Empty,
    /// A controller's address is not `HOST` or `HOST:PORT`.
    #[error(
        "robot '{robot}': '{address}' is not a controller's address ({problem}): write HOST, HOST:PORT or [IPv6]:PORT"
    )]
    Address {
        /// The robot id.
        robot: String,
        /// The address as written.
        address: String,
        /// What is wrong with it.
        problem: &'static str,
    },
    /// The session could not be configured or opened.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// Zenoh failed.
    #[error("zenoh: {0}")]
    Zenoh(#[from] zenoh::Error),
}

/// The controllers and key prefix of a fleet file's text (`source_name` names it in errors);
/// `key_prefix` when the file sets none.
pub fn parse_fleet(
    text: &str,
    source_name: &str,
    key_prefix: &str,
) -> Result<(String, Vec<ControllerSettings>), GatewayError> {
    let file: FleetFile = toml::from_str(text).map_err(|e| GatewayError::FleetFile {
        source_name: source_name.to_owned(),
        message: e.message().to_owned(),
    })?;
    Ok((
        file.key_prefix.unwrap_or_else(|| key_prefix.to_owned()),
        file.controllers,
    ))
}

impl ControllerSettings {
    /// Robot `robot`'s controller at `address` (`HOST`, `HOST:PORT`, `[IPv6]:PORT` or a bare
    /// IPv6 address; RTDE's port unless one is given), with the other settings' defaults.
    pub fn at(robot: &str, address: &str) -> Result<Self, GatewayError> {
        let refuse = |problem| GatewayError::Address {
            robot: robot.to_owned(),
            address: address.to_owned(),
            problem,
        };
        let port_of = |text: &str| match text.parse::<u16>() {
            Ok(0) | Err(_) => Err(refuse("the port is not a number within 1 … 65535")),
            Ok(port) => Ok(port),
        };
        let (host, port) = if let Some(rest) = address.strip_prefix('[') {
            let (host, after) = rest
                .split_once(']')
                .ok_or_else(|| refuse("an unclosed '['"))?;
            match after {
                "" => (host, DEFAULT_PORT),
                _ => match after.strip_prefix(':') {
                    Some(port) => (host, port_of(port)?),
                    None => return Err(refuse("text after ']' that is not ':PORT'")),
                },
            }
        } else {
            // Bare, a host carries no colon and an IPv6 address several (and no port).
            match address.split_once(':') {
                Some((host, port)) if !port.contains(':') => (host, port_of(port)?),
                _ => (address, DEFAULT_PORT),
            }
        };
        if host.is_empty() || host.chars().any(char::is_whitespace) {
            return Err(refuse("no host"));
        }
        Ok(Self {
            robot: robot.to_owned(),
            host: host.to_owned(),
            port,
            dashboard_port: default_dashboard_port(),
            frequency_hz: default_frequency_hz(),
            record: None,
        })
    }
}

/// Checks every robot id (each named once) and frequency of `controllers`, of which there is
/// at least one.
fn check_controllers(controllers: &[ControllerSettings]) -> Result<(), GatewayError> {
    if controllers.is_empty() {
        return Err(GatewayError::Empty);
    }
    let mut robots = HashSet::new();
    for controller in controllers {
        keys::robot_id(&controller.robot).map_err(|problem| GatewayError::Key {
            text: controller.robot.clone(),
            problem,
        })?;
        if !robots.insert(controller.robot.as_str()) {
            return Err(GatewayError::DuplicateRobot {
                robot: controller.robot.clone(),
            });
        }
        if !(controller.frequency_hz > 0.0 && controller.frequency_hz <= 500.0) {
            return Err(GatewayError::Frequency {
                robot: controller.robot.clone(),
                frequency_hz: controller.frequency_hz,
            });
        }
    }
    Ok(())
}

impl GatewaySettings {
    /// Checks every robot id, the prefix and the frequencies.
    pub fn check(&self) -> Result<KeySpace, GatewayError> {
        let keys = KeySpace::new(&self.key_prefix).map_err(|problem| GatewayError::Key {
            text: self.key_prefix.clone(),
            problem,
        })?;
        check_controllers(&self.controllers)?;
        Ok(keys)
    }
}

/// Controllers streamed on a session the caller owns: `serve`'s, for the robots it names with
/// `rtde`. The links are those of `armtwin gateway rtde`, reconnection, controller facts,
/// liveliness tokens and recording alike.
pub struct InService {
    controllers: Vec<ControllerSettings>,
}

impl InService {
    /// Checks `controllers` (see [`GatewaySettings::check`]).
    pub fn new(controllers: Vec<ControllerSettings>) -> Result<Self, GatewayError> {
        check_controllers(&controllers)?;
        Ok(Self { controllers })
    }
}

impl Beside for InService {
    fn start(self: Box<Self>, session: Session, keys: KeySpace) -> Box<dyn Running> {
        let (stop, stopped) = watch::channel(false);
        let mut links = tokio::task::JoinSet::new();
        for controller in self.controllers {
            links.spawn(link::run(
                session.clone(),
                keys.clone(),
                controller,
                stopped.clone(),
            ));
        }
        Box::new(Links { stop, links })
    }
}

/// The running links of [`InService`].
struct Links {
    stop: watch::Sender<bool>,
    links: tokio::task::JoinSet<()>,
}

impl Running for Links {
    fn stop(self: Box<Self>) -> Pin<Box<dyn Future<Output = ()> + Send>> {
        let Self { stop, mut links } = *self;
        Box::pin(async move {
            let _ = stop.send(true);
            bounded("stopping the controllers' links", TEARDOWN_STEP, async {
                while links.join_next().await.is_some() {}
            })
            .await;
        })
    }
}

/// Streams every controller until `shutdown` completes. Returns an error only for what the
/// operator configured; a controller's faults are logged and retried.
pub async fn run(
    settings: GatewaySettings,
    shutdown: impl Future<Output = ()>,
) -> Result<(), GatewayError> {
    let keys = settings.check()?;
    let mut zenoh = zenoh_config_of(&settings.zenoh)?;
    // One publisher declaration on the mesh for the whole fleet's joints.
    aggregate_publishers(&mut zenoh, &[keys.every_robot(Stream::Joints)])?;
    let session = zenoh::open(zenoh).await?;
    info!(
        controllers = settings.controllers.len(),
        zid = %session.zid(),
        "gateway rtde started"
    );
    let links = Box::new(InService {
        controllers: settings.controllers,
    })
    .start(session.clone(), keys);
    shutdown.await;
    info!("stopping the gateway");
    links.stop().await;
    close_session(&session).await?;
    Ok(())
}

#[cfg(test)]
#[allow(
    clippy::float_cmp,
    reason = "stamps of these tests are sums exact in binary: equality is what is meant"
)]
mod tests {
    use super::*;

    #[test]
    fn a_fleet_file_names_its_controllers() {
        let text = r#"
            key_prefix = "plant"
            [[controllers]]
            robot = "cell-1/ur10e"
            host = "10.0.0.5"
            [[controllers]]
            robot = "cell-2/ur5e"
            host = "10.0.0.6"
            port = 30005
            dashboard_port = 29005
            frequency = 125
            record = "cell-2.csv"
        "#;
        let (prefix, controllers) = parse_fleet(text, "gateways.toml", "twin").unwrap();
        assert_eq!(prefix, "plant");
        assert_eq!(controllers[0].port, 30004);
        assert_eq!(controllers[0].frequency_hz, 500.0);
        assert_eq!(controllers[1].port, 30005);
        assert_eq!(controllers[0].dashboard_port, 29999);
        assert_eq!(controllers[1].dashboard_port, 29005);
        assert_eq!(controllers[1].record, Some(PathBuf::from("cell-2.csv")));
        let settings = GatewaySettings {
            zenoh: ZenohSection::default(),
            key_prefix: prefix,
            controllers,
        };
        settings.check().unwrap();
    }

    #[test]
    fn a_controller_is_found_by_its_address() {
        let at = |address| {
            ControllerSettings::at("r", address)
                .map(|c| (c.host, c.port))
                .map_err(|e| e.to_string())
        };
        assert_eq!(at("10.0.0.5"), Ok(("10.0.0.5".to_owned(), 30004)));
        assert_eq!(at("10.0.0.5:30005"), Ok(("10.0.0.5".to_owned(), 30005)));
        assert_eq!(
            at("ur-cell1.local"),
            Ok(("ur-cell1.local".to_owned(), 30004))
        );
        assert_eq!(at("fd00::5"), Ok(("fd00::5".to_owned(), 30004)));
        assert_eq!(at("[fd00::5]:30005"), Ok(("fd00::5".to_owned(), 30005)));
        assert_eq!(at("[fd00::5]"), Ok(("fd00::5".to_owned(), 30004)));
        for bad in [
            "10.0.0.5:",
            "10.0.0.5:0",
            "10.0.0.5:99999",
            "[fd00::5",
            "[fd00::5]x",
            "",
            ":30004",
            "a b",
        ] {
            let error = at(bad).expect_err(bad);
            assert!(
                error.starts_with(&format!("robot 'r': '{bad}' is not a controller's address")),
                "{error}"
            );
        }
        let controller = ControllerSettings::at("r", "h").unwrap();
        assert_eq!(
            (controller.dashboard_port, controller.frequency_hz),
            (29999, 500.0)
        );
    }

    #[test]
    fn bad_fleets_are_named() {
        let error = parse_fleet("[[controllers]]\nrobot = \"a\"\n", "g.toml", "twin").unwrap_err();
        assert!(
            error
                .to_string()
                .starts_with("g.toml: missing field `host`"),
            "{error}"
        );
        let controller = |robot: &str, frequency_hz: f64| ControllerSettings {
            robot: robot.to_owned(),
            host: "h".to_owned(),
            port: 1,
            dashboard_port: 2,
            frequency_hz,
            record: None,
        };
        let check = |controllers| {
            GatewaySettings {
                zenoh: ZenohSection::default(),
                key_prefix: "twin".to_owned(),
                controllers,
            }
            .check()
            .unwrap_err()
            .to_string()
        };
        assert_eq!(
            check(vec![controller("a", 500.0), controller("a", 125.0)]),
            "robot 'a' is named by two controllers"
        );
        assert!(check(vec![controller("a/*", 500.0)]).starts_with("'a/*'"));
        assert!(check(vec![controller("a", 1000.0)]).contains("1000 Hz"));
        assert_eq!(check(vec![]), "no controller to stream");
    }
}
