//! `armtwin`'s flags: the clap definitions of every command's arguments, their value enums and
//! parsers, and the zenohd-style mesh flags the benchmarks share.
//!
//! Owns what the command line accepts (names, defaults, help text) and how each value maps to the
//! library's types; must not read files or compute (the commands in [`crate::cmd`] do).

use std::path::PathBuf;

use armtwin_access::certs::names::RouterName;
use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_service::config::{Overrides, ZenohInsert, ZenohMode};
use clap::{Args, Parser, Subcommand, ValueEnum};

/// armtwin: live digital twin for robot arms.
#[derive(Debug, Parser)]
#[command(name = "armtwin", version, about, propagate_version = true)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// armtwin's commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Forward kinematics: TCP pose of one joint configuration (JSON), or of every row of a CSV.
    Fk(FkArgs),
    /// List the built-in robot models with their DH parameters and joint limits.
    Models(ModelsArgs),
    /// Inverse dynamics: the joint torques (JSON) for positions, velocities and accelerations.
    Torques(TorquesArgs),
    /// Run the live twin service on Zenoh (peer on tcp/127.0.0.1:7447 by default).
    Serve(ServeArgs),
    /// Publish a recording (CSV) to the mesh as a gateway would, for `armtwin serve` to twin.
    Replay(ReplayArgs),
    /// Record the live streams of robots (joints, measured, and the twin pose and deviation when
    /// a service publishes them) as MCAP files, for a duration or until Ctrl-C.
    Record(RecordArgs),
    /// Run a recording through the twin offline: report (JSON, Markdown), per-row CSV and plots;
    /// exits 3 when --max-position-error or --max-angle-error is exceeded.
    Validate(ValidateArgs),
    /// FMI 2.0 co-simulation FMU of the forward kinematics.
    Fmu(FmuArgs),
    /// Inverse kinematics: every joint configuration reaching a TCP pose (JSON), nearest the
    /// seed first; exits 1 with the reason when the pose is unreachable.
    Ik(IkArgs),
    /// Identify the robot's kinematics (calibration.conf deltas, optionally the tool) from a
    /// recording with measured poses; writes calibration.conf, report.json, report.md and a plot.
    Calibrate(CalibrateArgs),
    /// Stream robot controllers into the mesh as a gateway: `gateway rtde` for Universal Robots.
    Gateway(GatewayArgs),
    /// The router's access control from a fleet description (TOML: which certificate name speaks
    /// for which robots; which are armtwin, dashboards, operators), printed as JSON5 or written
    /// into a router configuration between its `armtwin acl` marks.
    Acl(AclArgs),
    /// The fleet's certificates from its description, by role: the CA, the router's (the only
    /// one that may serve, for the names clients reach it by), and one client certificate per
    /// name (its common name, what the router's access control matches). PEM files, keys 0600.
    Certs(CertsArgs),
    /// A new token for the dashboard: the secret (shown once) and the `[[http.tokens]]` entry
    /// that holds its salted digest.
    HttpToken(HttpTokenArgs),
    /// A user of the OPC UA server: its password read from stdin (one line), the
    /// `[[opcua.users]]` entry that holds its salted digest printed.
    OpcuaUser(OpcuaUserArgs),
    /// The service's configuration: `config show` prints the effective one.
    Config(ConfigArgs),
    /// Check a configuration before it runs: each robot's model, calibration and tool, the
    /// controllers `serve` would stream (ports, model), who may reach each door, the recorder's
    /// folder. One line per check (OK, WARN, FAIL); exits 1 when one fails.
    Doctor(DoctorArgs),
}

/// `armtwin doctor` arguments.
#[derive(Debug, Args)]
pub struct DoctorArgs {
    /// The configuration file (TOML); without it, the built-in `config/armtwin.toml`.
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// A Prometheus (`http://HOST:PORT`) to ask whether it scrapes this service's `/metrics`, under
    /// which job, and whether it holds armtwin's alerting rules.
    #[arg(long, value_name = "URL")]
    pub prometheus: Option<String>,
}

/// `armtwin config` arguments.
#[derive(Debug, Args)]
pub struct ConfigArgs {
    /// What to do with it.
    #[command(subcommand)]
    pub command: ConfigCommand,
}

/// `armtwin config` subcommands.
#[derive(Debug, Subcommand)]
pub enum ConfigCommand {
    /// Print the effective configuration as TOML: the file layered over the built-in default,
    /// every default filled in, each robot completed from `[robots.default]`, checked as `serve`
    /// checks it.
    Show(ConfigShowArgs),
}

/// `armtwin config show` arguments.
#[derive(Debug, Args)]
pub struct ConfigShowArgs {
    /// The configuration file (TOML); without it, the built-in `config/armtwin.toml`.
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

/// `armtwin opcua-user` arguments.
#[derive(Debug, Args)]
pub struct OpcuaUserArgs {
    /// The user name clients sign in with.
    pub name: String,
}

/// `armtwin http-token` arguments.
#[derive(Debug, Args)]
pub struct HttpTokenArgs {
    /// The token's name: the user name of HTTP Basic authentication, and what logs call it.
    pub name: String,
    /// What it may read: `viewer` (every page, stream and /metrics) or `metrics` (/metrics only,
    /// for Prometheus).
    #[arg(long, default_value = "viewer", value_parser = ["viewer", "metrics"])]
    pub role: String,
}

/// `armtwin acl` arguments.
#[derive(Debug, Args)]
pub struct AclArgs {
    /// The fleet description (config/fleet.toml is a commented example).
    pub fleet: PathBuf,
    /// Write the section into this router configuration, between its `// BEGIN access_control`
    /// and `// END access_control` lines, instead of printing it.
    #[arg(long, value_name = "ROUTER_CONFIG")]
    pub update: Option<PathBuf>,
}

/// `armtwin certs` arguments.
#[derive(Debug, Args)]
pub struct CertsArgs {
    /// The fleet description (config/fleet.toml is a commented example).
    pub fleet: PathBuf,
    /// The folder to write `ca.pem`, `ca.key`, `router.pem`, `router.key` and `<name>.pem`,
    /// `<name>.key` for every name of the fleet into (made if missing).
    pub dir: PathBuf,
    /// A name clients reach the router by, written into its certificate: a DNS name or an IP
    /// address (repeatable) [default: localhost and 127.0.0.1].
    #[arg(long = "router-name", value_name = "NAME")]
    pub router_names: Vec<RouterName>,
    /// How long the router's and the names' certificates are valid, in days (the CA: ten years).
    #[arg(long, default_value_t = 365, value_name = "DAYS")]
    pub days: u32,
    /// Replace files that already exist (otherwise the command refuses and writes nothing).
    #[arg(long)]
    pub force: bool,
}

/// `armtwin gateway` arguments.
#[derive(Debug, Args)]
pub struct GatewayArgs {
    /// Which controllers.
    #[command(subcommand)]
    pub command: GatewayCommand,
}

/// `armtwin gateway` commands.
#[derive(Debug, Subcommand)]
pub enum GatewayCommand {
    /// Universal Robots controllers over RTDE (port 30004): joint angles and the controller's TCP
    /// pose, published as binary joint messages; reconnects by itself.
    Rtde(RtdeArgs),
}

/// `armtwin gateway rtde` arguments.
#[derive(Debug, Args)]
pub struct RtdeArgs {
    /// The controller's address (one robot; or -c for a fleet).
    #[arg(long, required_unless_present = "config", conflicts_with = "config")]
    pub host: Option<String>,
    /// The controller's RTDE port.
    #[arg(long, default_value_t = armtwin_codec::rtde::DEFAULT_PORT)]
    pub port: u16,
    /// The controller's dashboard server port, read for its model and serial number (another
    /// one for a controller behind NAT).
    #[arg(long, default_value_t = armtwin_gateway::dashboard::DEFAULT_PORT)]
    pub dashboard_port: u16,
    /// Robot id to publish as (may span several key chunks, e.g. plant-a/cell-3/ur10e-07).
    #[arg(long, required_unless_present = "config", conflicts_with = "config")]
    pub robot: Option<String>,
    /// Output frequency to ask the controller for (Hz; e-Series up to 500, CB3 up to 125).
    #[arg(long, value_name = "HZ", default_value_t = armtwin_gateway::DEFAULT_FREQUENCY_HZ)]
    pub frequency: f64,
    /// Also write every data package to this CSV (`ur_rtde`'s form: `armtwin validate` reads it),
    /// appended to an earlier run's of the same columns; a file of other columns is left alone.
    #[arg(long, value_name = "FILE", conflicts_with = "config")]
    pub record: Option<PathBuf>,
    /// A fleet file: `[[controllers]]` with `robot`, `host`, optional `port`,
    /// `dashboard_port`, `frequency`, `record`; one connection each, one Zenoh session.
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// The key prefix of the service to feed: its `[service] key_prefix` (keys
    /// `<prefix>/joints/<robot>`, …).
    #[arg(long, default_value = armtwin_mesh::keys::DEFAULT_PREFIX)]
    pub prefix: String,
    /// How to join the mesh; without flags, as `armtwin replay` (a peer connecting to where a
    /// default `armtwin serve` listens).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// `armtwin fmu` arguments.
#[derive(Debug, Args)]
pub struct FmuArgs {
    /// What to do.
    #[command(subcommand)]
    pub command: FmuCommand,
}

/// `armtwin fmu` commands.
#[derive(Debug, Subcommand)]
pub enum FmuCommand {
    /// Package one robot (catalog model, calibration, tool, frame) as an FMU file.
    Build(FmuBuildArgs),
}

/// `armtwin fmu build` arguments.
#[derive(Debug, Args)]
pub struct FmuBuildArgs {
    /// The robot (catalog models only; the tool becomes the `tcp_*` parameters' start values).
    #[command(flatten)]
    pub robot: RobotArgs,
    /// The FMU file to write, e.g. `UR10e_FK.fmu`; its name without `.fmu` is the model
    /// identifier.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// The FMU library (`libarmtwin_fmu.so`); by default the one next to this executable, built
    /// by `cargo build --release -p armtwin-fmu`.
    #[arg(long, value_name = "PATH")]
    pub library: Option<PathBuf>,
}

/// Which recording and how to read it; shared by `replay` and `validate`.
#[derive(Debug, Args)]
pub struct RecordingArgs {
    /// The recording: the UR10e FMU report's CSV form, a ROS 2 export or a UR RTDE recording
    /// (recognised from the header), any CSV with --joint-columns, or a rosbag2 recording (a bag
    /// directory, or its `.mcap` / `.db3` file).
    pub recording: PathBuf,
    /// Seconds between rows, ignoring the recording's time column (e.g. 0.1 for the report's
    /// `fmpy_inputs.csv`, whose time column is a row index).
    #[arg(long, value_name = "SECONDS")]
    pub period: Option<f64>,
    /// Joint angle columns, in joint order, for a header armtwin does not recognise (or to
    /// override what it recognises): `--joint-columns j1,j2,j3,j4,j5,j6`.
    #[arg(long, value_name = "NAMES", value_delimiter = ',')]
    pub joint_columns: Vec<String>,
    /// With --joint-columns: the time column.
    #[arg(long, value_name = "NAME", requires = "joint_columns")]
    pub time_column: Option<String>,
    /// With --time-column: its unit.
    #[arg(long, value_enum, default_value_t = TimeUnit::S)]
    pub time_unit: TimeUnit,
    /// With --joint-columns: the measured pose columns, `x,y,z` then the orientation columns of
    /// --pose-form.
    #[arg(
        long,
        value_name = "NAMES",
        value_delimiter = ',',
        requires = "joint_columns"
    )]
    pub pose_columns: Vec<String>,
    /// With --pose-columns: the orientation form.
    #[arg(long, value_enum, default_value_t = PoseFormArg::Quaternion)]
    pub pose_form: PoseFormArg,
    /// For a rosbag2 recording: the `sensor_msgs/msg/JointState` topic.
    #[arg(long, value_name = "TOPIC", default_value = "/joint_states")]
    pub joint_topic: String,
    /// For a rosbag2 recording: the `geometry_msgs/msg/PoseStamped` topic of the measured pose,
    /// in the robot's `base` frame.
    #[arg(
        long,
        value_name = "TOPIC",
        default_value = "/tcp_pose_broadcaster/pose"
    )]
    pub pose_topic: String,
    /// For a rosbag2 recording: the robot's `tf_prefix`, of its joint names and of its `base`
    /// frame.
    #[arg(long, value_name = "PREFIX", default_value = "")]
    pub tf_prefix: String,
}

/// `--time-unit` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TimeUnit {
    /// Seconds.
    S,
    /// Milliseconds.
    Ms,
    /// Microseconds.
    Us,
    /// Nanoseconds.
    Ns,
}

/// `--pose-form` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PoseFormArg {
    /// `qx,qy,qz,qw`.
    Quaternion,
    /// `roll,pitch,yaw` (rad).
    Rpy,
    /// A UR rotation vector `rx,ry,rz` (rad).
    Rotvec,
}

/// `armtwin replay` arguments.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recording.
    #[command(flatten)]
    pub input: RecordingArgs,
    /// Robot id to publish as (may span several key chunks, e.g. plant-a/cell-3/ur10e-07).
    #[arg(long)]
    pub robot: String,
    /// Playback speed relative to the recording's time (2.0 = twice as fast).
    #[arg(long, default_value_t = 1.0, conflicts_with = "max_rate")]
    pub speed: f64,
    /// Publish as fast as the transport takes it.
    #[arg(long)]
    pub max_rate: bool,
    /// The key prefix of the service to feed: its `[service] key_prefix` (keys
    /// `<prefix>/joints/<robot>`, …).
    #[arg(long, default_value = armtwin_mesh::keys::DEFAULT_PREFIX)]
    pub prefix: String,
    /// How to join the mesh; without flags, as the default `armtwin serve` configuration says
    /// (a peer, multicast scouting off), connecting to where it listens (tcp/127.0.0.1:7447).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// `armtwin record` arguments.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// Robot ids, or key expressions over them (`r1`, `cell-1/*`, `**`).
    #[arg(required_unless_present = "incident", value_name = "ROBOTS")]
    pub robots: Vec<String>,
    /// A directory for one file per robot (`<robot, escaped>.mcap`), or a file ending in
    /// `.mcap` for a single robot (the first heard; others are refused).
    #[arg(
        short = 'o',
        long = "out",
        value_name = "DIR|FILE.mcap",
        required_unless_present = "incident"
    )]
    pub out: Option<PathBuf>,
    /// Instead: ask the twin of ROBOT for an incident file now, as an operator does, and print
    /// the file's name; the twin's flight recorder writes it (docs/recorder.md).
    #[arg(long, value_name = "ROBOT", conflicts_with_all = ["robots", "out", "duration"])]
    pub incident: Option<String>,
    /// With --incident: seconds before the robot's newest sample [default: the twin's
    /// `[recorder] pre_s`, which is also the most].
    #[arg(long, value_name = "SECONDS", requires = "incident")]
    pub pre_s: Option<f64>,
    /// With --incident: seconds after it [default: the twin's `[recorder] post_s`, also the most].
    #[arg(long, value_name = "SECONDS", requires = "incident")]
    pub post_s: Option<f64>,
    /// Seconds to record [default: until Ctrl-C].
    #[arg(long, value_name = "SECONDS")]
    pub duration: Option<f64>,
    /// Joints of the robots' arms: a joint message with another count is skipped as malformed.
    #[arg(long, default_value_t = 6)]
    pub joints: usize,
    /// Robots recorded at most: ids are the mesh's to choose, and each costs an open file.
    #[arg(long, default_value_t = 64)]
    pub max_robots: usize,
    /// Messages waiting to be written; more are dropped, and counted.
    #[arg(long, value_name = "MESSAGES", default_value_t = 65_536)]
    pub queue: usize,
    /// The key prefix of the streams: the service's `[service] key_prefix`.
    #[arg(long, default_value = armtwin_mesh::keys::DEFAULT_PREFIX)]
    pub prefix: String,
    /// How to join the mesh; without flags, as a client of the default `armtwin serve` (multicast
    /// scouting off, connecting to tcp/127.0.0.1:7447), which routes every robot's streams to it.
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

/// `armtwin validate` arguments.
#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// The recording.
    #[command(flatten)]
    pub input: RecordingArgs,
    /// The robot the recording is of.
    #[command(flatten)]
    pub robot: RobotArgs,
    /// A service configuration whose alignment, window and default alarm settings to use
    /// (default: the built-in one, as `armtwin serve`).
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Directory for the report (default: `<recording name>-validation`).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Fail (exit 3) if the largest position error exceeds this many metres.
    #[arg(long, value_name = "METRES")]
    pub max_position_error: Option<f64>,
    /// Fail (exit 3) if the largest rotation angle between twin and measured exceeds this many
    /// radians.
    #[arg(long, value_name = "RADIANS")]
    pub max_angle_error: Option<f64>,
    /// Also compare the joint torques of a UR RTDE recording (`target_moment_*`,
    /// `actual_current_*`) with the model's inverse dynamics: writes `dynamics.csv` and a
    /// `dynamics` object in `report.json`.
    #[arg(long)]
    pub dynamics: bool,
    /// With --dynamics, for a recording without `payload` and `payload_cog_*` columns: the
    /// payload as mass (kg) and centre of gravity in the flange frame (m).
    #[arg(
        long,
        value_name = "MASS,CX,CY,CZ",
        value_delimiter = ',',
        allow_negative_numbers = true,
        requires = "dynamics"
    )]
    pub payload: Vec<f64>,
}

/// `armtwin serve` arguments.
#[derive(Debug, Args)]
pub struct ServeArgs {
    /// The configuration file (TOML); without it, the built-in `config/armtwin.toml`.
    #[arg(short = 'c', long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// How to join the mesh; the flags override the configuration's `[zenoh]`.
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    /// Serve the dashboard and `/metrics` on this address, e.g. 127.0.0.1:8080 (replaces the
    /// configuration's `[http] listen`).
    #[arg(long = "http", value_name = "ADDRESS")]
    pub http_listen: Option<std::net::SocketAddr>,
    /// Serve every twin over OPC UA (OPC 40010 Robotics) on this endpoint, e.g.
    /// `opc.tcp://127.0.0.1:4840` (replaces the configuration's `[opcua] endpoint`).
    #[arg(long = "opcua", value_name = "URL")]
    pub opcua_endpoint: Option<String>,
}

/// How a command joins the Zenoh mesh, in Zenoh's own style (as `zenohd`): the same flags, with
/// the same meaning, for every command that opens a session. Each flag overrides the command's
/// `[zenoh]` settings ([`armtwin_mesh::zenoh_section::ZenohSection::overridden`]); what is not given stays as they say.
#[derive(Debug, Clone, Default, Args)]
pub struct ZenohArgs {
    /// Zenoh mode [default: the configuration's, peer].
    #[arg(short = 'm', long, value_enum, value_name = "MODE")]
    pub mode: Option<ZenohModeArg>,
    /// Endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable; replaces the configuration's
    /// list).
    #[arg(short = 'l', long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// Endpoint to connect to, e.g. tcp/10.0.0.5:7447 (repeatable; replaces the configuration's
    /// list).
    #[arg(short = 'e', long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Any Zenoh configuration value, as `zenohd --cfg`: a JSON5 VALUE at the configuration path
    /// KEY, e.g. `--cfg transport/shared_memory/enabled:false` or
    /// `--cfg scouting/multicast/enabled:true` (repeatable; applied last, so it wins).
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    pub cfg: Vec<ZenohInsert>,
}

impl ZenohArgs {
    /// The flags as configuration overrides.
    #[must_use]
    pub fn overrides(&self) -> Overrides {
        Overrides {
            mode: self.mode.map(ZenohMode::from),
            listen: self.listen.clone(),
            connect: self.connect.clone(),
            cfg: self.cfg.clone(),
            http_listen: None,
            opcua_endpoint: None,
        }
    }
}

/// `-m/--mode` values: the library's [`ZenohMode`], named as Zenoh names its session roles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ZenohModeArg {
    /// Talks to every session it reaches, directly.
    Peer,
    /// Talks through one router (or peer) it connects to.
    Client,
    /// Routes for clients and other routers.
    Router,
}

impl From<ZenohModeArg> for ZenohMode {
    fn from(mode: ZenohModeArg) -> Self {
        match mode {
            ZenohModeArg::Peer => Self::Peer,
            ZenohModeArg::Client => Self::Client,
            ZenohModeArg::Router => Self::Router,
        }
    }
}

/// The chain of a URDF `--model`: its base and tip links.
#[derive(Debug, Default, Args)]
pub struct ChainLinks {
    /// With a URDF `--model`: the chain's base link, the frame poses are in (default: the root
    /// link).
    #[arg(long, value_name = "LINK")]
    pub base_link: Option<String>,
    /// With a URDF `--model`: the chain's tip link, the pose's (default: the one leaf link).
    #[arg(long, value_name = "LINK")]
    pub tip_link: Option<String>,
}

/// Which robot: model, its calibration, its tool, and the output frame. Shared by every command
/// that computes poses.
#[derive(Debug, Args)]
pub struct RobotArgs {
    /// Catalog model (see `armtwin models`), a custom arm's TOML file, or a URDF file.
    #[arg(long, default_value = "ur10e")]
    pub model: String,
    /// With a URDF `--model`: the chain.
    #[command(flatten)]
    pub links: ChainLinks,
    /// The robot's factory calibration: the controller's `calibration.conf` or the YAML written by
    /// ROS `ur_calibration`.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Tool (TCP) offset `x,y,z,rx,ry,rz` as on the UR pendant: metres and a rotation vector in
    /// radians. Write `--tcp=-0.1,...` when the first value is negative.
    #[arg(long, value_name = "X,Y,Z,RX,RY,RZ", value_parser = parse_tcp)]
    pub tcp: Option<TcpOffset>,
    /// Frame of the output pose: the controller's `base` (as RTDE `actual_TCP_pose`) or ROS
    /// `base_link` (base rotated π about z).
    #[arg(long, value_enum, default_value_t = FrameArg::Base)]
    pub frame: FrameArg,
}

/// `--frame` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FrameArg {
    /// The controller's base frame.
    Base,
    /// ROS `base_link`.
    #[value(name = "base_link")]
    BaseLink,
}

impl From<FrameArg> for OutputFrame {
    fn from(frame: FrameArg) -> Self {
        match frame {
            FrameArg::Base => Self::Base,
            FrameArg::BaseLink => Self::BaseLink,
        }
    }
}

/// `armtwin fk` arguments.
#[derive(Debug, Args)]
pub struct FkArgs {
    /// The robot.
    #[command(flatten)]
    pub robot: RobotArgs,
    /// Joint angles are in degrees (outputs stay in metres and radians).
    #[arg(long)]
    pub deg: bool,
    /// Also print the 4×4 homogeneous matrix (row-major) of the pose.
    #[arg(long)]
    pub matrix: bool,
    /// Read joint angles from a CSV (`q1..qn` or `time,q1..qn` columns; `-` for stdin) and write
    /// the pose CSV `time,x,y,z,roll,pitch,yaw,qx,qy,qz,qw` to stdout.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["joints", "matrix"])]
    pub csv: Option<PathBuf>,
    /// Joint angles q1 … qn (radians unless --deg).
    #[arg(allow_negative_numbers = true, value_name = "Q")]
    pub joints: Vec<f64>,
}

/// `armtwin torques` arguments.
#[derive(Debug, Args)]
pub struct TorquesArgs {
    /// A catalog model with published inertias (the UR arms), or a URDF file (its `<inertial>`s).
    #[arg(long, default_value = "ur10e")]
    pub model: String,
    /// With a URDF `--model`: the chain.
    #[command(flatten)]
    pub links: ChainLinks,
    /// Joint positions, base to tip (rad, or m for a prismatic joint), comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        allow_negative_numbers = true,
        required = true
    )]
    pub q: Vec<f64>,
    /// Joint velocities (rad/s or m/s); zeros when left out.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub qd: Vec<f64>,
    /// Joint accelerations (rad/s² or m/s²); zeros when left out.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub qdd: Vec<f64>,
}

/// `armtwin models` arguments.
#[derive(Debug, Args)]
pub struct ModelsArgs {
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write the URDF of this model (a catalog arm or a custom arm's TOML) to stdout, with
    /// `--calibration`, `--tcp` and `--frame` folded into its joint origins.
    #[arg(long, value_name = "MODEL", conflicts_with = "json")]
    pub urdf: Option<String>,
    /// With `--urdf`: the robot's factory calibration (as `armtwin fk`'s).
    #[arg(long, value_name = "FILE", requires = "urdf")]
    pub calibration: Option<PathBuf>,
    /// With `--urdf`: the tool (TCP) offset `x,y,z,rx,ry,rz` (as `armtwin fk`'s); the tip link is
    /// then `tcp`, else `tool0` (the flange).
    #[arg(long, value_name = "X,Y,Z,RX,RY,RZ", value_parser = parse_tcp, requires = "urdf")]
    pub tcp: Option<TcpOffset>,
    /// With `--urdf`: the root link's frame, the controller's `base` or ROS `base_link`.
    #[arg(long, value_enum, default_value_t = FrameArg::Base, requires = "urdf")]
    pub frame: FrameArg,
}

/// Parses `x,y,z,rx,ry,rz`; also accepts the pendant's `p[x, y, z, rx, ry, rz]` spelling.
fn parse_tcp(text: &str) -> Result<TcpOffset, String> {
    let inner = text.trim();
    let inner = inner.strip_prefix('p').unwrap_or(inner);
    let inner = inner
        .strip_prefix('[')
        .and_then(|t| t.strip_suffix(']'))
        .unwrap_or(inner);
    let values = inner
        .split(',')
        .map(|item| {
            item.trim()
                .parse::<f64>()
                .map_err(|_| format!("'{}' is not a number", item.trim()))
        })
        .collect::<Result<Vec<f64>, String>>()?;
    let values: [f64; 6] = values
        .try_into()
        .map_err(|v: Vec<f64>| format!("expected 6 values x,y,z,rx,ry,rz, got {}", v.len()))?;
    TcpOffset::from_ur_pose(values).ok_or_else(|| "every value must be finite".to_owned())
}

/// `armtwin ik` arguments.
#[derive(Debug, Args)]
pub struct IkArgs {
    /// The robot.
    #[command(flatten)]
    pub robot: RobotArgs,
    /// The TCP pose `x,y,z,qx,qy,qz,qw` in the output frame (metres; quaternion in wire order,
    /// normalised here). Write `--pose=-0.4,...` when the first value is negative.
    #[arg(
        long,
        value_name = "X,Y,Z,QX,QY,QZ,QW",
        value_delimiter = ',',
        allow_negative_numbers = true,
        required = true
    )]
    pub pose: Vec<f64>,
    /// Joint angles q1,…,q6 (rad) to order the solutions by (nearest first) and to pick each
    /// joint's turn; also gives q6 where the wrist is singular.
    #[arg(
        long,
        value_name = "Q1,…,Q6",
        value_delimiter = ',',
        allow_negative_numbers = true
    )]
    pub seed: Vec<f64>,
}

/// `armtwin calibrate` arguments.
#[derive(Debug, Args)]
pub struct CalibrateArgs {
    /// The recording (any layout `validate` reads; it must carry measured poses).
    #[command(flatten)]
    pub input: RecordingArgs,
    /// The robot: the nominal model and the tool the recording was made with (`--calibration`
    /// is refused: the fit starts from the nominal arm).
    #[command(flatten)]
    pub robot: RobotArgs,
    /// Also fit the tool offset, starting from --tcp (or the flange).
    #[arg(long)]
    pub fit_tcp: bool,
    /// Fraction of the rows, taken from the end of the recording, held out from the fit.
    #[arg(long, default_value_t = 0.3, value_name = "FRACTION")]
    pub holdout: f64,
    /// Metres one radian of orientation error weighs as in the fit.
    #[arg(long, default_value_t = 1.0, value_name = "M_PER_RAD")]
    pub orientation_weight: f64,
    /// Directory for calibration.conf and the report.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}
