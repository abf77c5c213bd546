//! Universal Robots' Real-Time Data Exchange (RTDE) protocol, client side, as UR's RTDE guide
//! describes it: the packages a client sends, the answers and data packages a controller sends,
//! the output recipe they agree on, and the handshake as a state machine that is handed frames
//! and hands back bytes to send.
//!
//! Owns every RTDE byte layout and every check on what a controller sends: a frame whose size,
//! type or contents do not match what was agreed is an [`RtdeError`] naming what is wrong, never
//! a panic, and nothing is allocated by a length read from a frame. Must not open a socket, read
//! a clock or know Zenoh: the gateway (`armtwin gateway rtde`) moves the bytes.
//!
//! - [`frame`]: the package header (`u16` size big-endian, including the header, then a `u8`
//!   type), request encoders, and [`frame::FrameSplitter`] that cuts a byte stream into frames.
//! - [`recipe`]: variable types, the output recipe the controller answers, and one data package
//!   decoded into an [`RtdeSample`].
//! - [`handshake`]: protocol version (2, else 1 for older CB3 controllers), controller version,
//!   output setup (variables the controller does not know are dropped and the setup sent again),
//!   start; then data packages.
//! - [`record`]: samples as the CSV `ur_rtde` records (`timestamp,actual_q_0,…`), which
//!   `armtwin validate` reads.

pub mod frame;
pub mod handshake;
pub mod recipe;
pub mod record;

pub use frame::{Frame, FrameSplitter, PackageType};
pub use handshake::{Handshake, Progress};
pub use recipe::{Recipe, RtdeSample, VariableType};

use thiserror::Error;

/// The controller's RTDE port.
pub const DEFAULT_PORT: u16 = 30004;

/// The RTDE protocol versions a client may ask for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProtocolVersion {
    /// Version 1 (CB3 before 3.3): no output frequency, no recipe ids.
    V1,
    /// Version 2: output frequency, recipe ids on setups and data packages.
    V2,
}

impl ProtocolVersion {
    /// The number on the wire.
    #[must_use]
    pub fn number(self) -> u16 {
        match self {
            Self::V1 => 1,
            Self::V2 => 2,
        }
    }
}

/// What is wrong with what a controller sent (or with what the gateway was asked to send).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RtdeError {
    /// A header's size is smaller than the header itself.
    #[error("frame size {size} is smaller than the 3-byte header")]
    FrameSize {
        /// The size the header gives.
        size: u16,
    },
    /// More bytes were handed to the splitter than it holds before its frames are taken.
    #[error("{bytes} bytes waiting for frames, more than the {limit} the splitter holds")]
    Overflow {
        /// Bytes that would be buffered.
        bytes: usize,
        /// The splitter's bound.
        limit: usize,
    },
    /// A package of a type that has no place at this point of the exchange.
    #[error("unexpected package '{}' (0x{kind:02x}) while {during}", char::from(*kind))]
    Unexpected {
        /// The package type byte.
        kind: u8,
        /// What the client was waiting for.
        during: &'static str,
    },
    /// A package whose payload is not the size its type (or the recipe) requires.
    #[error("{package} payload of {got} bytes, expected {expected}")]
    PayloadSize {
        /// The package type.
        package: PackageType,
        /// The size required.
        expected: usize,
        /// The size received.
        got: usize,
    },
    /// A package that ends before one of its fields.
    #[error("{package} ends before its {field}")]
    Truncated {
        /// The package type.
        package: PackageType,
        /// The field that is missing.
        field: &'static str,
    },
    /// A text field that is not UTF-8.
    #[error("{package}: {field} is not UTF-8")]
    NotUtf8 {
        /// The package type.
        package: PackageType,
        /// The field.
        field: &'static str,
    },
    /// The output setup answer names a type RTDE does not have.
    #[error("output setup answers an unknown type '{name}' for variable '{variable}'")]
    UnknownType {
        /// The variable requested at that place.
        variable: String,
        /// The type named (at most 32 bytes of it).
        name: String,
    },
    /// The output setup answer gives a variable another type than RTDE defines for it.
    #[error("output setup answers type {got} for '{variable}', which is {expected}")]
    TypeMismatch {
        /// The variable.
        variable: &'static str,
        /// Its type in RTDE.
        expected: VariableType,
        /// The type answered.
        got: VariableType,
    },
    /// The output setup answer lists another number of types than variables were requested.
    #[error("output setup answers {answered} types for {requested} variables")]
    VariableCount {
        /// Variables requested.
        requested: usize,
        /// Types answered.
        answered: usize,
    },
    /// A data package of another recipe than the one agreed.
    #[error("data package of recipe {got}, expected recipe {expected}")]
    RecipeId {
        /// The recipe agreed on.
        expected: u8,
        /// The recipe the package names.
        got: u8,
    },
    /// The output setup was refused (recipe id 0), or a variable is in use.
    #[error("the controller refused the output setup: {reason}")]
    SetupRefused {
        /// Why, as far as the answer says.
        reason: String,
    },
    /// A variable the gateway cannot do without is unknown to the controller.
    #[error("the controller does not know '{variable}', which the gateway needs")]
    Required {
        /// The variable.
        variable: &'static str,
    },
    /// The controller accepts neither protocol version 2 nor 1.
    #[error("the controller accepts neither RTDE protocol version 2 nor 1")]
    NoProtocol,
    /// The controller refused to start (or pause) the data stream.
    #[error("the controller refused {request}")]
    Refused {
        /// What was asked.
        request: &'static str,
    },
    /// An output frequency the controller cannot take.
    #[error("output frequency {frequency_hz} Hz is not within (0, 500]")]
    Frequency {
        /// The frequency asked for.
        frequency_hz: f64,
    },
    /// The variable names do not fit in one package.
    #[error("the variable names take {bytes} bytes, more than one package holds ({limit})")]
    SetupTooLarge {
        /// Bytes the names take.
        bytes: usize,
        /// What a package holds.
        limit: usize,
    },
}

impl RtdeError {
    /// A short, stable name for logs and counters.
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Self::FrameSize { .. } => "frame_size",
            Self::Overflow { .. } => "overflow",
            Self::Unexpected { .. } => "unexpected_package",
            Self::PayloadSize { .. } => "payload_size",
            Self::Truncated { .. } => "truncated",
            Self::NotUtf8 { .. } => "not_utf8",
            Self::UnknownType { .. } => "unknown_type",
            Self::TypeMismatch { .. } => "type_mismatch",
            Self::VariableCount { .. } => "variable_count",
            Self::RecipeId { .. } => "recipe_id",
            Self::SetupRefused { .. } => "setup_refused",
            Self::Required { .. } => "required_variable",
            Self::NoProtocol => "no_protocol",
            Self::Refused { .. } => "refused",
            Self::Frequency { .. } => "frequency",
            Self::SetupTooLarge { .. } => "setup_too_large",
        }
    }
}

#[cfg(test)]
mod tests;
