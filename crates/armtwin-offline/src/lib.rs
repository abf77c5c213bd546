//! armtwin on recordings and files rather than as the live service.
//!
//! - [`validate`]: `armtwin validate`, a recording through the pipeline, with its report files
//!   and SVG plots.
//! - [`calibrate`]: `armtwin calibrate`, a recording's kinematics identified, with its report.
//! - [`replay`]: `armtwin replay`, a recording published as a gateway would.
//! - [`record`]: `armtwin record`, live streams of chosen robots written as MCAP files.
//! - [`rosbag`]: rosbag2 recordings (MCAP, sqlite3) read into the rows a CSV becomes.
//! - [`fmu_package`]: `armtwin fmu build`, the FMU archive.
//!
//! Must not know the service or a door: `replay` and `record` take the mesh alone.

pub mod calibrate;
pub mod fmu_package;
pub mod record;
pub mod replay;
pub mod rosbag;
pub mod validate;
