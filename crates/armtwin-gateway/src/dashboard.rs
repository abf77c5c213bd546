//! A controller's dashboard server (TCP port 29999), read for the controller's model and serial
//! number. The protocol, as UR documents it and `ur_rtde`'s `DashboardClient` speaks it: the
//! server greets with one line; each command is one line, each answer one line. `get robot
//! model` answers the family (`UR10`); `get serial number` (controller software 5.6 and later)
//! the serial number, digits only; an older server answers a command it does not know with a sentence
//! (`Could not understand: …`), which is no serial number.
//!
//! Owns the connection, its bounds (one overall timeout, lines of at most [`MAX_LINE_BYTES`])
//! and reading the answers; must not decide what the facts mean (the service compares the
//! model with its configuration).

use std::time::Duration;

use thiserror::Error;
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::time::timeout;

use armtwin_mesh::controller::{MAX_TEXT_CHARS, clean_text};

/// The controller's dashboard server port.
pub const DEFAULT_PORT: u16 = 29999;

/// How long the whole exchange may take.
pub const EXCHANGE_TIMEOUT: Duration = Duration::from_secs(2);

/// Longest line read: the server's lines are sentences, never more.
const MAX_LINE_BYTES: u64 = 1024;

/// What the dashboard server says of the controller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// The answer to `get robot model`, if it names a model (`UR10`).
    pub model: Option<String>,
    /// The answer to `get serial number`, if it is one (digits).
    pub serial: Option<String>,
}

/// Why the dashboard server could not be read.
#[derive(Debug, Error)]
pub enum DashboardError {
    /// No connection.
    #[error("cannot connect to {address}: {source}")]
    Connect {
        /// `host:port`.
        address: String,
        /// Why.
        source: std::io::Error,
    },
    /// The exchange did not finish in time.
    #[error("{address} did not answer within {EXCHANGE_TIMEOUT:?}")]
    Silent {
        /// `host:port`.
        address: String,
    },
    /// The connection failed or closed mid-exchange.
    #[error("{address}: {source}")]
    Io {
        /// `host:port`.
        address: String,
        /// Why.
        source: std::io::Error,
    },
}

/// Reads the model and serial number of the controller whose dashboard server is at
/// `host:port`, within [`EXCHANGE_TIMEOUT`].
pub async fn read_identity(host: &str, port: u16) -> Result<Identity, DashboardError> {
    Ok(read(host, port, false).await?.0)
}

/// [`read_identity`], and the controller's software version (`PolyscopeVersion`: major, minor,
/// bugfix, build), which tells an e-Series `UR10` from a CB3's where no RTDE link is open.
pub async fn read_identity_and_version(
    host: &str,
    port: u16,
) -> Result<(Identity, Option<[u32; 4]>), DashboardError> {
    read(host, port, true).await
}

async fn read(
    host: &str,
    port: u16,
    with_version: bool,
) -> Result<(Identity, Option<[u32; 4]>), DashboardError> {
    let address = format!("{host}:{port}");
    match timeout(
        EXCHANGE_TIMEOUT,
        exchange(host, port, &address, with_version),
    )
    .await
    {
        Ok(result) => result,
        Err(_) => Err(DashboardError::Silent { address }),
    }
}

async fn exchange(
    host: &str,
    port: u16,
    address: &str,
    with_version: bool,
) -> Result<(Identity, Option<[u32; 4]>), DashboardError> {
    let socket =
        TcpStream::connect((host, port))
            .await
            .map_err(|source| DashboardError::Connect {
                address: address.to_owned(),
                source,
            })?;
    let io = |source| DashboardError::Io {
        address: address.to_owned(),
        source,
    };
    let mut connection = BufReader::new(socket);
    // The greeting.
    read_line(&mut connection).await.map_err(io)?;
    let model = ask(&mut connection, "get robot model").await.map_err(io)?;
    let serial = ask(&mut connection, "get serial number")
        .await
        .map_err(io)?;
    let version = if with_version {
        version_of(&ask(&mut connection, "PolyscopeVersion").await.map_err(io)?)
    } else {
        None
    };
    // Polite, not needed: the server closes a connection its client closed.
    let _ = connection.get_mut().write_all(b"quit\n").await;
    let identity = Identity {
        model: Some(model).filter(|answer| is_model(answer)),
        serial: Some(serial).filter(|answer| is_serial(answer)),
    };
    Ok((identity, version))
}

/// The version in a `PolyscopeVersion` answer (`URSoftware 5.21.0.9 (Jan 01 2025)`): its first
/// word of four dotted numbers.
fn version_of(answer: &str) -> Option<[u32; 4]> {
    answer.split_whitespace().find_map(|word| {
        let mut parts = word.split('.').map(str::parse::<u32>);
        let version = [
            parts.next()?.ok()?,
            parts.next()?.ok()?,
            parts.next()?.ok()?,
            parts.next()?.ok()?,
        ];
        parts.next().is_none().then_some(version)
    })
}

/// Sends `command` and reads its answer line.
async fn ask(connection: &mut BufReader<TcpStream>, command: &str) -> std::io::Result<String> {
    connection
        .get_mut()
        .write_all(format!("{command}\n").as_bytes())
        .await?;
    read_line(connection).await
}

/// One line, cleaned and bounded; an error if the server closed the connection first.
async fn read_line(connection: &mut BufReader<TcpStream>) -> std::io::Result<String> {
    let mut line = Vec::new();
    let read = (&mut *connection)
        .take(MAX_LINE_BYTES)
        .read_until(b'\n', &mut line)
        .await?;
    if read == 0 {
        return Err(std::io::ErrorKind::UnexpectedEof.into());
    }
    if line.last() != Some(&b'\n') {
        // Over the bound: the rest of the line is not read.
        return Err(std::io::ErrorKind::InvalidData.into());
    }
    Ok(clean_text(&String::from_utf8_lossy(&line), MAX_TEXT_CHARS))
}

/// A model answer: `UR` and digits, possibly more (`UR10`, `UR5e`), one word.
fn is_model(answer: &str) -> bool {
    let prefix_is_ur = answer
        .get(..2)
        .is_some_and(|prefix| prefix.eq_ignore_ascii_case("ur"));
    prefix_is_ur
        && answer
            .get(2..)
            .is_some_and(|rest| rest.starts_with(|c: char| c.is_ascii_digit()))
        && !answer.contains(' ')
}

/// A serial number answer: digits only (as `DashboardClient::getSerialNumber` checks).
fn is_serial(answer: &str) -> bool {
    !answer.is_empty() && answer.bytes().all(|b| b.is_ascii_digit())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_that_are_no_model_or_serial_are_left_out() {
        assert!(is_model("UR10") && is_model("UR5e") && is_model("ur16"));
        assert!(!is_model("Could not understand: 'get robot model'") && !is_model("UR"));
        assert!(!is_model("é10"));
        assert!(is_serial("20235500001"));
        assert!(!is_serial("") && !is_serial("Could not understand: 'get serial number'"));
    }

    #[test]
    fn a_software_version_is_read_from_its_answer() {
        assert_eq!(
            version_of("URSoftware 5.21.0.9 (Jan 01 2025)"),
            Some([5, 21, 0, 9])
        );
        assert_eq!(
            version_of("URSoftware 3.15.7.106331 (Mar 22 2021)"),
            Some([3, 15, 7, 106_331])
        );
        assert_eq!(version_of("Could not understand: 'PolyscopeVersion'"), None);
        assert_eq!(version_of("URSoftware 5.21 (x)"), None);
    }
}
