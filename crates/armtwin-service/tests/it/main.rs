//! The library's integration tests as one binary, so the library and its dependencies are linked
//! once: one module per feature, each opening with its purpose. The tests that run the `armtwin`
//! binary are in armtwin-cli's tests; the codecs' tests are beside this directory.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

mod calibrate;
mod common;
mod dashboard;
mod ros2_bag;
mod ros2_client;
mod ros2_config;
mod ros2_fixtures;
mod ros2_live;
mod service;
mod validate;
