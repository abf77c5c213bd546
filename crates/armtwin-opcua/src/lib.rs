//! armtwin's OPC UA server: every twinned robot as an OPC 40010 (Robotics) `MotionDeviceSystem`
//! under DI's `DeviceSet`, with armtwin's own `Twin` object beside its motion device, for the
//! SCADA, MES and historians of a plant.
//!
//! Layout:
//! - `settings`: `[opcua]` as written and checked (endpoint, users, certificates, sampling);
//! - `password`: the users' PBKDF2 digests;
//! - `access`: who may sign in, and read-only for all;
//! - `reading`: what the server reads of the fleet ([`TwinSource`], implemented by the service);
//! - `manager`: the DI and Robotics `NodeSet`s imported in memory, no writes;
//! - `robot`: one robot's nodes and what each variable shows;
//! - `robots`: armtwin's namespace, the robots' nodes made from the fleet when a request names
//!   them, and the monitored variables sampled;
//! - `alarms`: each alarm's name and severity, and the changes between two readings;
//! - `conditions`: the alarms as Alarms & Conditions, retained until acknowledged and confirmed;
//! - `condition_event`: a condition's state as an `AlarmConditionType` event;
//! - `methods`: `Acknowledge`, `Confirm` (operators) and `ConditionRefresh`;
//! - `rejected`: the client certificates the server refused, kept within bounds;
//! - `server`: the server and the sampler thread (monitored variables, condition events).
//!
//! Knows nothing of armtwin's twins: the service hands it [`RobotReading`]s.

mod access;
mod alarms;
mod condition_event;
mod conditions;
mod manager;
mod methods;
mod password;
mod reading;
mod rejected;
mod robot;
mod robots;
mod server;
mod settings;

pub use manager::NodeSetError;
pub use password::{PasswordHash, PasswordHashError};
pub use reading::{
    AlarmReading, ControllerReading, DeviationStats, IdentifiedPayload, PayloadReading,
    PoseReading, RobotReading, TwinSource,
};
pub use rejected::{MAX_REJECTED_BYTES, MAX_REJECTED_FILES};
pub use server::{BoundServer, OpcUaError, OpcUaServer};
pub use settings::{OpcUaSection, OpcUaSettings, Role, SettingsError, User, UserSection};
