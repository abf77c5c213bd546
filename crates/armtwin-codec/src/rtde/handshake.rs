//! One RTDE connection's exchange as a state machine: it is handed each frame the controller
//! sends and says what to send back, when the stream has started (with the recipe agreed) and
//! what each data package holds. Must not read or write a socket or a clock.
//!
//! The order, as UR's RTDE guide gives it: request protocol version 2 (a controller that refuses
//! it is asked for version 1, which older CB3 software speaks), ask the controller's version,
//! set up the outputs, start. Variables the controller answers `NOT_FOUND` for are dropped and
//! the setup is sent again without them: a recipe naming an unknown variable is not one the
//! controller streams.

use super::frame::{self, Frame, PackageType};
use super::recipe::{Recipe, RtdeSample, SetupAnswer, VARIABLES, Variable};
use super::{ProtocolVersion, RtdeError};

/// The controller's software version.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ControllerVersion {
    /// 3 for CB3, 5 for e-Series.
    pub major: u32,
    /// Minor.
    pub minor: u32,
    /// Bugfix.
    pub bugfix: u32,
    /// Build.
    pub build: u32,
}

/// A text message from the controller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TextMessage {
    /// 0 exception, 1 error, 2 warning, 3 info.
    pub level: u8,
    /// The message (invalid UTF-8 replaced).
    pub message: String,
    /// Where it comes from (empty under protocol 1).
    pub source: String,
}

/// What the stream was started with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Started {
    /// The protocol version agreed.
    pub version: ProtocolVersion,
    /// The controller's version.
    pub controller: ControllerVersion,
    /// The recipe of every data package.
    pub recipe: Recipe,
    /// Variables requested that the controller does not have, dropped from the recipe.
    pub dropped: Vec<&'static str>,
}

/// What a frame leads to.
#[derive(Debug, Clone, PartialEq)]
#[allow(
    clippy::large_enum_variant,
    reason = "a sample per data package is the common case: boxing it would allocate per package"
)]
pub enum Progress {
    /// Send these bytes to the controller.
    Send(Vec<u8>),
    /// The data packages have started.
    Started(Started),
    /// One data package.
    Sample(RtdeSample),
    /// A text message.
    Text(TextMessage),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Protocol(ProtocolVersion),
    ControllerVersion,
    Setup,
    Start,
    Streaming,
}

impl State {
    fn waiting_for(self) -> &'static str {
        match self {
            Self::Protocol(_) => "waiting for the protocol version answer",
            Self::ControllerVersion => "waiting for the controller version",
            Self::Setup => "waiting for the output setup answer",
            Self::Start => "waiting for the start answer",
            Self::Streaming => "streaming",
        }
    }
}

/// One connection's exchange, from the first request to the data packages.
#[derive(Debug, Clone)]
pub struct Handshake {
    state: State,
    /// The version agreed (the one asked for until the answer comes).
    agreed: ProtocolVersion,
    frequency_hz: f64,
    requested: Vec<&'static Variable>,
    dropped: Vec<&'static str>,
    controller: Option<ControllerVersion>,
    recipe: Option<Recipe>,
}

impl Handshake {
    /// A new exchange asking for [`VARIABLES`] at `frequency_hz`, and the first bytes to send.
    pub fn new(frequency_hz: f64) -> Result<(Self, Vec<u8>), RtdeError> {
        // Checked now, not after three round trips.
        frame::setup_outputs(ProtocolVersion::V2, frequency_hz, &[])?;
        let handshake = Self {
            state: State::Protocol(ProtocolVersion::V2),
            agreed: ProtocolVersion::V2,
            frequency_hz,
            requested: VARIABLES.iter().collect(),
            dropped: Vec::new(),
            controller: None,
            recipe: None,
        };
        Ok((
            handshake,
            frame::request_protocol_version(ProtocolVersion::V2),
        ))
    }

    /// Whether the data packages have started.
    #[must_use]
    pub fn is_streaming(&self) -> bool {
        self.state == State::Streaming
    }

    fn version(&self) -> ProtocolVersion {
        match self.state {
            State::Protocol(version) => version,
            _ => self.agreed,
        }
    }

    /// Takes one frame from the controller.
    pub fn on_frame(&mut self, frame: Frame<'_>) -> Result<Progress, RtdeError> {
        let unexpected = RtdeError::Unexpected {
            kind: frame.kind,
            during: self.state.waiting_for(),
        };
        let Some(package) = frame.package() else {
            return Err(unexpected);
        };
        if package == PackageType::TextMessage {
            return text_message(frame.payload, self.version()).map(Progress::Text);
        }
        match (self.state, package) {
            (State::Protocol(version), PackageType::RequestProtocolVersion) => {
                if accepted(package, frame.payload)? {
                    self.agreed = version;
                    self.state = State::ControllerVersion;
                    Ok(Progress::Send(frame::request_controller_version()))
                } else if version == ProtocolVersion::V2 {
                    self.state = State::Protocol(ProtocolVersion::V1);
                    Ok(Progress::Send(frame::request_protocol_version(
                        ProtocolVersion::V1,
                    )))
                } else {
                    Err(RtdeError::NoProtocol)
                }
            }
            (State::ControllerVersion, PackageType::GetUrcontrolVersion) => {
                let Ok(bytes) = <[u8; 16]>::try_from(frame.payload) else {
                    return Err(RtdeError::PayloadSize {
                        package,
                        expected: 16,
                        got: frame.payload.len(),
                    });
                };
                let word = |at: usize| {
                    u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
                };
                self.controller = Some(ControllerVersion {
                    major: word(0),
                    minor: word(4),
                    bugfix: word(8),
                    build: word(12),
                });
                self.state = State::Setup;
                self.setup()
            }
            (State::Setup, PackageType::SetupOutputs) => {
                let answer = SetupAnswer::parse(frame.payload, &self.requested, self.agreed)?;
                if answer.not_found.is_empty() {
                    self.recipe = Some(answer.recipe);
                    self.state = State::Start;
                    return Ok(Progress::Send(frame::start()));
                }
                if let Some(required) = self
                    .requested
                    .iter()
                    .find(|v| v.required && answer.not_found.contains(&v.name))
                {
                    return Err(RtdeError::Required {
                        variable: required.name,
                    });
                }
                self.requested
                    .retain(|variable| !answer.not_found.contains(&variable.name));
                self.dropped.extend(answer.not_found);
                self.setup()
            }
            (State::Start, PackageType::Start) => {
                if !accepted(package, frame.payload)? {
                    return Err(RtdeError::Refused {
                        request: "to start the data packages",
                    });
                }
                self.state = State::Streaming;
                let (Some(controller), Some(recipe)) = (self.controller, self.recipe.clone())
                else {
                    return Err(unexpected);
                };
                Ok(Progress::Started(Started {
                    version: self.agreed,
                    controller,
                    recipe,
                    dropped: self.dropped.clone(),
                }))
            }
            (State::Streaming, PackageType::DataPackage) => match &self.recipe {
                Some(recipe) => recipe.decode(frame.payload).map(Progress::Sample),
                None => Err(unexpected),
            },
            _ => Err(unexpected),
        }
    }

    fn setup(&self) -> Result<Progress, RtdeError> {
        let names: Vec<&str> = self.requested.iter().map(|v| v.name).collect();
        frame::setup_outputs(self.agreed, self.frequency_hz, &names).map(Progress::Send)
    }
}

/// A one-byte answer: accepted (non-zero) or not.
fn accepted(package: PackageType, payload: &[u8]) -> Result<bool, RtdeError> {
    match payload {
        [answer] => Ok(*answer != 0),
        _ => Err(RtdeError::PayloadSize {
            package,
            expected: 1,
            got: payload.len(),
        }),
    }
}

/// A text message: protocol 2 `(length u8, message, length u8, source, level u8)`, protocol 1
/// `(level u8, message…)`.
fn text_message(payload: &[u8], version: ProtocolVersion) -> Result<TextMessage, RtdeError> {
    let package = PackageType::TextMessage;
    let truncated = |field| RtdeError::Truncated { package, field };
    let text = |bytes: &[u8]| String::from_utf8_lossy(bytes).into_owned();
    match version {
        ProtocolVersion::V1 => {
            let (&level, message) = payload.split_first().ok_or(truncated("level"))?;
            Ok(TextMessage {
                level,
                message: text(message),
                source: String::new(),
            })
        }
        ProtocolVersion::V2 => {
            let (&length, rest) = payload.split_first().ok_or(truncated("message length"))?;
            let (message, rest) = rest
                .split_at_checked(usize::from(length))
                .ok_or(truncated("message"))?;
            let (&length, rest) = rest.split_first().ok_or(truncated("source length"))?;
            let (source, rest) = rest
                .split_at_checked(usize::from(length))
                .ok_or(truncated("source"))?;
            match rest {
                [level] => Ok(TextMessage {
                    level: *level,
                    message: text(message),
                    source: text(source),
                }),
                [] => Err(truncated("level")),
                _ => Err(RtdeError::PayloadSize {
                    package,
                    expected: payload.len() - rest.len() + 1,
                    got: payload.len(),
                }),
            }
        }
    }
}
