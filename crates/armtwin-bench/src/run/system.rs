//! A system under test: a subprocess on a loopback port, waited for until it listens and stopped
//! (SIGTERM, then SIGKILL) when dropped.
//!
//! Owns the subprocess's lifetime; must not know which system it runs.

use std::net::{TcpListener, TcpStream};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use super::{STARTUP_TIMEOUT, STOP_TIMEOUT};

/// A subprocess under test, stopped (SIGTERM, then SIGKILL) when dropped.
pub(super) struct SystemUnderTest {
    pub(super) child: Child,
    pub(super) endpoint: String,
}

impl SystemUnderTest {
    pub(super) fn pid(&self) -> u32 {
        self.child.id()
    }

    pub(super) fn stop(mut self) {
        self.terminate();
    }

    pub(super) fn terminate(&mut self) {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return;
        }
        // std offers only SIGKILL; SIGTERM lets armtwin shut down as in production.
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        drop(self.child.stdin.take());
        let deadline = Instant::now() + STOP_TIMEOUT;
        while Instant::now() < deadline {
            if matches!(self.child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for SystemUnderTest {
    fn drop(&mut self) {
        self.terminate();
    }
}

pub(super) fn free_port() -> Result<u16> {
    let listener = TcpListener::bind("127.0.0.1:0").context("finding a free port")?;
    Ok(listener.local_addr()?.port())
}

/// Waits until `port` accepts connections (the system under test is listening).
pub(super) fn wait_listening(port: u16, child: &mut Child) -> Result<()> {
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
