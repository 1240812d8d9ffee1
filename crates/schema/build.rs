//! Compiles `proto/` with protox (pure Rust: no system protoc), then generates the prost
//! messages, the tonic service traits and the pbjson serde impls, so the JSON of every
//! message is its canonical proto3 JSON.
//!
//! No transport code (tonic's `connect`): it would make every user of the schema compile
//! hyper. A client makes its `Channel` with its own tonic and hands it to `new`.

use std::{env, fs, path::PathBuf};

use prost::Message;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The workspace's `proto/` (the Python client reads it too), from this crate's directory.
    let protos = ["../../proto/trinocular/v1/trinocular.proto"];
    println!("cargo:rerun-if-changed=../../proto");
    let out_dir = PathBuf::from(env::var("OUT_DIR")?);

    let fds = protox::compile(protos, ["../../proto"])?;
    let descriptor_path = out_dir.join("trinocular_descriptor.bin");
    fs::write(&descriptor_path, fds.encode_to_vec())?;

    tonic_prost_build::configure()
        .build_client(true)
        .build_server(true)
        .build_transport(false)
        // A request that does not decode is INVALID_ARGUMENT, not tonic's INTERNAL.
        .codec_path("crate::codec::InputCodec")
        .compile_fds(fds)?;

    let descriptors = fs::read(&descriptor_path)?;
    pbjson_build::Builder::new()
        .register_descriptors(&descriptors)?
        .emit_fields()
        .build(&[".trinocular"])?;
    Ok(())
}
