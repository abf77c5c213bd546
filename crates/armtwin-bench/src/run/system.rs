//! A system under test: a subprocess on a loopback port, waited for until it listens and stopped
//! (SIGTERM, then SIGKILL) when dropped.
//!
//! Owns the subprocess's lifetime; must not know which system it runs, beyond how `armtwin serve`
//! is started on a configuration.

use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use super::{STARTUP_TIMEOUT, STOP_TIMEOUT};
use crate::net;

/// A subprocess under test, stopped (SIGTERM, then SIGKILL) when dropped.
pub(crate) struct SystemUnderTest {
    pub(crate) child: Child,
    pub(crate) endpoint: String,
}

impl SystemUnderTest {
    /// `armtwin serve -c <config>` (written with `text` first), listening on a free loopback
    /// port, its own logs warnings and up only.
    pub(crate) fn armtwin(armtwin: &Path, config: &Path, text: &str) -> Result<Self> {
        let port = free_port()?;
        let endpoint = net::loopback_endpoint(port);
        std::fs::write(config, text).with_context(|| format!("writing {}", config.display()))?;
        let mut child = Command::new(armtwin)
            .arg("serve")
            .arg("-c")
            .arg(config)
            .args(["-l", &endpoint])
            .env("RUST_LOG", "armtwin=warn,zenoh=error")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", armtwin.display()))?;
        wait_listening(port, &mut child)?;
        Ok(Self { child, endpoint })
    }

    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Stops the subprocess ([`terminate`](Self::terminate)); the seconds from SIGTERM until it
    /// exited, `None` when it had to be killed (or had exited already).
    pub(crate) fn stop(mut self) -> Option<f64> {
        self.terminate()
    }

    /// SIGTERM, then SIGKILL after [`STOP_TIMEOUT`]; the seconds from SIGTERM until the
    /// subprocess exited by itself, if it did.
    pub(crate) fn terminate(&mut self) -> Option<f64> {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return None;
        }
        // std offers only SIGKILL; SIGTERM lets armtwin shut down as in production.
        let signalled = Instant::now();
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        drop(self.child.stdin.take());
        let deadline = signalled + STOP_TIMEOUT;
        while Instant::now() < deadline {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return Some(signalled.elapsed().as_secs_f64());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        None
    }
}

impl Drop for SystemUnderTest {
    fn drop(&mut self) {
        let _stopped_s = self.terminate();
    }
}

pub(crate) fn free_port() -> Result<u16> {
    let listener = TcpListener::bind("127.0.0.1:0").context("finding a free port")?;
    Ok(listener.local_addr()?.port())
}

/// Waits until `port` accepts connections (the system under test is listening).
pub(crate) fn wait_listening(port: u16, child: &mut Child) -> Result<()> {
    let deadline = Instant::now() + STARTUP_TIMEOUT;
    while Instant::now() < deadline {
        if TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return Ok(());
        }
        if let Some(status) = child.try_wait()? {
            bail!("the system under test exited before listening: {status}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    bail!("the system under test did not listen on port {port} within {STARTUP_TIMEOUT:?}")
}
