//! armtwin's codecs: the core's types to and from the formats armtwin reads and writes. Owns every
//! byte layout and every check on what arrives; must not know the network, the filesystem or the
//! clock: callers hand in bytes, readers, writers and the stamp to use when a message has none.
//!
//! - [`json`]: armtwin's JSON messages: gateway joints and measured poses in, the twin's pose,
//!   deviation, event, metrics, state and self-calibration estimate out.
//! - [`zser`]: the same gateway messages and outputs in Zenoh's own serialization.
//! - [`cdr`]: ROS 2 `JointState` and `PoseStamped` in CDR.
//! - [`ros2_attachment`]: the attachment `rmw_zenoh` puts on each sample.
//! - [`gateway`]: which of armtwin's decoders a message takes ([`gateway::Codec`]), and a
//!   gateway message into the pipeline in one call.
//! - [`decoded`]: one decoded message of any codec ([`decoded::Decoded`]) and the one way it
//!   steps its robot's twin; [`decoded::CodecError`], the rejection cause each codec's error has.
//! - [`ik`]: IK requests and answers as JSON.
//! - [`joint_csv`], [`recording`]: joint-angle CSV and recordings as people have them.
//! - [`rtde`]: Universal Robots' RTDE protocol (client side), frames to samples, and its CSV
//!   recordings.

pub mod cdr;
pub mod decoded;
pub mod gateway;
pub mod ik;
pub mod joint_csv;
pub mod json;
pub mod recording;
pub mod ros2_attachment;
pub mod rtde;
pub mod zser;

pub use armtwin_core::pose_fields::PoseFields;
