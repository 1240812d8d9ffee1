//! `trinocular`: the command line. Parses arguments, reads files, calls the library, writes
//! proto3 JSON. Errors go to stderr, name the offending field, and exit non-zero.

use std::{fs, path::PathBuf, process::ExitCode};

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use trinocular::api::{self, pb, InputError};
use trinocular::pipeline::match_segments;

#[derive(Parser)]
#[command(
    name = "trinocular",
    version,
    about = "Trinocular stereovision with line segments"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Match three segment lists and reconstruct 3D segments; prints a MatchResponse (JSON).
    Match(MatchArgs),
}

#[derive(Args)]
struct MatchArgs {
    /// A MatchRequest in proto3 JSON (instead of --calibration and --segments).
    #[arg(conflicts_with_all = ["calibration", "segments", "options"])]
    request: Option<PathBuf>,
    /// A Calibration in proto3 JSON.
    #[arg(long, requires = "segments")]
    calibration: Option<PathBuf>,
    /// A SegmentTriplet in proto3 JSON.
    #[arg(long, requires = "calibration")]
    segments: Option<PathBuf>,
    /// MatchOptions in proto3 JSON.
    #[arg(long)]
    options: Option<PathBuf>,
    /// Write the MatchResponse here instead of stdout.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

fn read(path: &PathBuf) -> anyhow::Result<String> {
    fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

/// Either an input problem (exit 2, names the field) or anything else (exit 1).
enum Failure {
    Input(InputError),
    Other(anyhow::Error),
}

impl From<InputError> for Failure {
    fn from(e: InputError) -> Self {
        Failure::Input(e)
    }
}
impl From<anyhow::Error> for Failure {
    fn from(e: anyhow::Error) -> Self {
        Failure::Other(e)
    }
}

fn build_request(args: &MatchArgs) -> Result<pb::MatchRequest, Failure> {
    if let Some(path) = &args.request {
        return Ok(api::from_json("request", &read(path)?)?);
    }
    let (Some(calibration), Some(segments)) = (&args.calibration, &args.segments) else {
        return Err(Failure::Other(anyhow::anyhow!(
            "give a REQUEST file, or --calibration and --segments"
        )));
    };
    let options = match &args.options {
        Some(path) => Some(api::from_json("options", &read(path)?)?),
        None => None,
    };
    Ok(pb::MatchRequest {
        calibration: Some(api::from_json("calibration", &read(calibration)?)?),
        options,
        input: Some(pb::match_request::Input::Segments(api::from_json(
            "segments",
            &read(segments)?,
        )?)),
    })
}

fn run_match(args: &MatchArgs) -> Result<(), Failure> {
    let request = build_request(args)?;
    let input = api::match_request(&request)?;
    let output =
        match_segments(&input.rig, &input.lists, &input.params).map_err(InputError::from)?;
    let json = api::to_json(&api::match_response(&output));
    match &args.output {
        Some(path) => fs::write(path, json + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?,
        None => println!("{json}"),
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Match(args) => run_match(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure::Input(e)) => {
            eprintln!("error: invalid input: {}: {}", e.field, e.message);
            ExitCode::from(2)
        }
        Err(Failure::Other(e)) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
