//! One integration test binary (link once): the CLI and the library's public API as a user
//! drives them.

mod accuracy;
mod bad_input;
mod browser;
mod calibration;
mod common;
mod golden;
mod images;
mod rigs;
mod service;
mod sessions;
mod tls;
