//! RTDE packages on the wire: the 3-byte header (`u16` size big-endian, counting the header,
//! then a `u8` type), the requests a client sends, and [`FrameSplitter`], which cuts the bytes a
//! controller sends into whole frames with a bounded buffer. Must not interpret a payload beyond
//! its header (the [`super::recipe`] and [`super::handshake`] modules do).

use std::fmt;

use super::{ProtocolVersion, RtdeError};

/// Bytes of a package header.
pub const HEADER_BYTES: usize = 3;

/// The largest frame: its size is a `u16`.
pub const MAX_FRAME_BYTES: usize = u16::MAX as usize;

/// The RTDE package types, by their ASCII letter on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PackageType {
    /// `V`: the client asks for a protocol version; the answer accepts it or not.
    RequestProtocolVersion,
    /// `v`: the controller's software version.
    GetUrcontrolVersion,
    /// `M`: a text message (either way).
    TextMessage,
    /// `U`: a data package of a recipe.
    DataPackage,
    /// `O`: the output recipe: frequency and variable names; the answer gives their types.
    SetupOutputs,
    /// `I`: the input recipe (not used by a receiving client).
    SetupInputs,
    /// `S`: start the data packages.
    Start,
    /// `P`: pause them.
    Pause,
}

impl PackageType {
    /// The type byte.
    #[must_use]
    pub fn byte(self) -> u8 {
        match self {
            Self::RequestProtocolVersion => b'V',
            Self::GetUrcontrolVersion => b'v',
            Self::TextMessage => b'M',
            Self::DataPackage => b'U',
            Self::SetupOutputs => b'O',
            Self::SetupInputs => b'I',
            Self::Start => b'S',
            Self::Pause => b'P',
        }
    }

    /// The type of a byte, if RTDE has one.
    #[must_use]
    pub fn from_byte(byte: u8) -> Option<Self> {
        Some(match byte {
            b'V' => Self::RequestProtocolVersion,
            b'v' => Self::GetUrcontrolVersion,
            b'M' => Self::TextMessage,
            b'U' => Self::DataPackage,
            b'O' => Self::SetupOutputs,
            b'I' => Self::SetupInputs,
            b'S' => Self::Start,
            b'P' => Self::Pause,
            _ => return None,
        })
    }
}

impl fmt::Display for PackageType {
    fn fmt(&self, formatter: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = match self {
            Self::RequestProtocolVersion => "REQUEST_PROTOCOL_VERSION",
            Self::GetUrcontrolVersion => "GET_URCONTROL_VERSION",
            Self::TextMessage => "TEXT_MESSAGE",
            Self::DataPackage => "DATA_PACKAGE",
            Self::SetupOutputs => "CONTROL_PACKAGE_SETUP_OUTPUTS",
            Self::SetupInputs => "CONTROL_PACKAGE_SETUP_INPUTS",
            Self::Start => "CONTROL_PACKAGE_START",
            Self::Pause => "CONTROL_PACKAGE_PAUSE",
        };
        formatter.write_str(name)
    }
}

/// One package: its type byte and its payload (what follows the header).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// The type byte as received (it may name no RTDE package).
    pub kind: u8,
    /// The payload.
    pub payload: &'a [u8],
}

impl Frame<'_> {
    /// The package type, if the byte names one.
    #[must_use]
    pub fn package(&self) -> Option<PackageType> {
        PackageType::from_byte(self.kind)
    }
}

/// A whole package: header and `payload`. The payload must leave the size within a `u16`; every
/// caller here builds payloads far below that, and [`setup_outputs`] checks its names first.
fn package(kind: PackageType, payload: &[u8]) -> Vec<u8> {
    let size = u16::try_from(HEADER_BYTES + payload.len()).unwrap_or(u16::MAX);
    let mut bytes = Vec::with_capacity(HEADER_BYTES + payload.len());
    bytes.extend_from_slice(&size.to_be_bytes());
    bytes.push(kind.byte());
    bytes.extend_from_slice(payload);
    bytes
}

/// `V`: asks for protocol `version`.
#[must_use]
pub fn request_protocol_version(version: ProtocolVersion) -> Vec<u8> {
    package(
        PackageType::RequestProtocolVersion,
        &version.number().to_be_bytes(),
    )
}

/// `v`: asks for the controller's version.
#[must_use]
pub fn request_controller_version() -> Vec<u8> {
    package(PackageType::GetUrcontrolVersion, &[])
}

/// `O`: the output recipe, `variables` comma-separated; protocol 2 puts the frequency (`f64`
/// big-endian, Hz) first.
pub fn setup_outputs(
    version: ProtocolVersion,
    frequency_hz: f64,
    variables: &[&str],
) -> Result<Vec<u8>, RtdeError> {
    if !(frequency_hz > 0.0 && frequency_hz <= 500.0) {
        return Err(RtdeError::Frequency { frequency_hz });
    }
    let mut payload = Vec::new();
    if version == ProtocolVersion::V2 {
        payload.extend_from_slice(&frequency_hz.to_be_bytes());
    }
    for (index, name) in variables.iter().enumerate() {
        if index > 0 {
            payload.push(b',');
        }
        payload.extend_from_slice(name.as_bytes());
    }
    let limit = MAX_FRAME_BYTES - HEADER_BYTES;
    if payload.len() > limit {
        return Err(RtdeError::SetupTooLarge {
            bytes: payload.len(),
            limit,
        });
    }
    Ok(package(PackageType::SetupOutputs, &payload))
}

/// `S`: starts the data packages.
#[must_use]
pub fn start() -> Vec<u8> {
    package(PackageType::Start, &[])
}

/// `P`: pauses them.
#[must_use]
pub fn pause() -> Vec<u8> {
    package(PackageType::Pause, &[])
}

/// Cuts a byte stream into frames. Holds at most one incomplete frame plus what one
/// [`FrameSplitter::extend`] adds, never more than [`FrameSplitter::LIMIT`] bytes: the caller
/// takes every whole frame ([`FrameSplitter::next_frame`] until `None`) before extending again.
#[derive(Debug, Default)]
pub struct FrameSplitter {
    buffer: Vec<u8>,
    /// Where the next frame starts in `buffer`: frames taken are removed at the next `extend`.
    start: usize,
}

impl FrameSplitter {
    /// The most bytes the splitter holds: one frame of the largest size, and as much again.
    pub const LIMIT: usize = 2 * MAX_FRAME_BYTES;

    /// An empty splitter.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends bytes read from the stream. Refused (nothing appended) if the splitter would then
    /// hold more than [`Self::LIMIT`] bytes: the caller did not take the frames it holds.
    pub fn extend(&mut self, bytes: &[u8]) -> Result<(), RtdeError> {
        self.buffer.drain(..self.start);
        self.start = 0;
        let total = self.buffer.len() + bytes.len();
        if total > Self::LIMIT {
            return Err(RtdeError::Overflow {
                bytes: total,
                limit: Self::LIMIT,
            });
        }
        self.buffer.extend_from_slice(bytes);
        Ok(())
    }

    /// The next whole frame, `None` until its bytes have all arrived. A header whose size is
    /// below the header's own is an error; the stream is then beyond repair (the caller drops
    /// the link).
    pub fn next_frame(&mut self) -> Result<Option<Frame<'_>>, RtdeError> {
        let waiting = &self.buffer[self.start..];
        let Some(&[high, low, kind]) = waiting.get(..HEADER_BYTES) else {
            return Ok(None);
        };
        let size = u16::from_be_bytes([high, low]);
        let frame_bytes = usize::from(size);
        if frame_bytes < HEADER_BYTES {
            return Err(RtdeError::FrameSize { size });
        }
        let Some(payload) = waiting.get(HEADER_BYTES..frame_bytes) else {
            return Ok(None);
        };
        self.start += frame_bytes;
        Ok(Some(Frame { kind, payload }))
    }

    /// Bytes held that belong to no frame taken yet.
    #[must_use]
    pub fn pending_bytes(&self) -> usize {
        self.buffer.len() - self.start
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_laid_out_as_the_guide_says() {
        assert_eq!(
            request_protocol_version(ProtocolVersion::V2),
            [0, 5, b'V', 0, 2]
        );
        assert_eq!(request_controller_version(), [0, 3, b'v']);
        assert_eq!(start(), [0, 3, b'S']);
        assert_eq!(pause(), [0, 3, b'P']);
        let setup = setup_outputs(ProtocolVersion::V2, 500.0, &["timestamp", "actual_q"]).unwrap();
        let mut expected = vec![0, 3 + 8 + 18, b'O'];
        expected.extend_from_slice(&500.0_f64.to_be_bytes());
        expected.extend_from_slice(b"timestamp,actual_q");
        assert_eq!(setup, expected);
        let v1 = setup_outputs(ProtocolVersion::V1, 125.0, &["timestamp"]).unwrap();
        assert_eq!(v1, [&[0, 12, b'O'][..], b"timestamp"].concat());
    }

    #[test]
    fn setups_out_of_bounds_are_refused() {
        for frequency_hz in [0.0, -1.0, 501.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                setup_outputs(ProtocolVersion::V2, frequency_hz, &["timestamp"])
                    .unwrap_err()
                    .kind(),
                "frequency"
            );
        }
        let long = "x".repeat(MAX_FRAME_BYTES);
        let error = setup_outputs(ProtocolVersion::V2, 125.0, &[&long]).unwrap_err();
        assert_eq!(error.kind(), "setup_too_large", "{error}");
    }

    #[test]
    fn frames_are_reassembled_byte_by_byte() {
        let mut stream = start();
        stream.extend(setup_outputs(ProtocolVersion::V2, 125.0, &["a", "b"]).unwrap());
        stream.extend(pause());
        let mut splitter = FrameSplitter::new();
        let mut frames = Vec::new();
        for byte in &stream {
            splitter.extend(std::slice::from_ref(byte)).unwrap();
            while let Some(frame) = splitter.next_frame().unwrap() {
                frames.push((frame.package(), frame.payload.len()));
            }
        }
        assert_eq!(
            frames,
            [
                (Some(PackageType::Start), 0),
                (Some(PackageType::SetupOutputs), 11),
                (Some(PackageType::Pause), 0)
            ]
        );
        assert_eq!(splitter.pending_bytes(), 0);
    }

    #[test]
    fn a_size_below_the_header_is_an_error() {
        let mut splitter = FrameSplitter::new();
        splitter.extend(&[0, 2, b'U', 0]).unwrap();
        assert_eq!(
            splitter.next_frame().unwrap_err(),
            RtdeError::FrameSize { size: 2 }
        );
    }

    #[test]
    fn the_buffer_is_bounded() {
        let mut splitter = FrameSplitter::new();
        // A header announcing the largest frame, then less than that: nothing to take yet.
        splitter.extend(&[0xff, 0xff, b'U']).unwrap();
        splitter.extend(&vec![0; MAX_FRAME_BYTES]).unwrap();
        assert_eq!(
            splitter.next_frame().unwrap().map(|f| f.payload.len()),
            Some(MAX_FRAME_BYTES - 3)
        );
        // The taken frame is released on the next extend; a caller that keeps extending
        // without taking frames is refused.
        splitter.extend(&vec![0; FrameSplitter::LIMIT - 3]).unwrap();
        let error = splitter.extend(&[0; 8]).unwrap_err();
        assert_eq!(error.kind(), "overflow");
    }
}
