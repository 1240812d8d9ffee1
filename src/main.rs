//! `trinocular`: the command line. Parses arguments, reads files, calls the library, writes
//! proto3 JSON (and pictures). Errors go to stderr, name the offending field, and exit
//! non-zero: 2 for bad input, 1 for anything else.

use std::{fs, path::Path, path::PathBuf, process::ExitCode};

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use serde::Serialize;
use trinocular::api::{
    self, pb, Executed, InputError, MatchInput, MatchSource, RunCalibration, RunMatch,
};
use trinocular::extract::decode::{self, DecodeLimits};
use trinocular::overlay;

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
    /// Render a synthetic room from three cameras, match it end to end and write pictures.
    Demo(DemoArgs),
    /// Extract the oriented segments of one image; prints a SegmentList (JSON).
    Extract(ExtractArgs),
    /// Match three images or segment lists and reconstruct 3D segments; prints a
    /// MatchResponse (JSON).
    Match(MatchArgs),
    /// Serve Match, sessions and Calibrate over gRPC and HTTP/JSON until SIGTERM or SIGINT.
    Serve(ServeArgs),
    /// Estimate the rig's three cameras from images of a known pattern (or from
    /// correspondences); prints a Calibration (JSON) that Match and sessions take unchanged,
    /// and each camera's reprojection error on stderr.
    Calibrate(CalibrateArgs),
    /// Read a calibration from other tools' files (Kalibr, OpenCV FileStorage, ROS
    /// CameraInfo), or write one in their formats.
    #[command(subcommand)]
    Calibration(CalibrationCommand),
    /// Write the calibration pattern as printable SVG pages at true size, one per board
    /// (board_0.svg, board_1.svg, …): print at 100 %, check the 100 mm bar, mount as labelled.
    Pattern(PatternArgs),
}

#[derive(Args)]
struct PatternArgs {
    /// A CalibrationPattern in proto3 JSON (default: the two-board pattern `calibrate` uses).
    #[arg(long)]
    pattern: Option<PathBuf>,
    /// Directory for the pages.
    #[arg(long, default_value = "pattern")]
    out: PathBuf,
}

#[derive(Subcommand)]
enum CalibrationCommand {
    /// Prints the Calibration (JSON) of Kalibr's camchain.yaml (--format kalibr), an OpenCV
    /// FileStorage file (opencv-yaml, opencv-xml) or three ROS CameraInfo files (ros).
    Import {
        #[arg(long, value_parser = ["kalibr", "opencv-yaml", "opencv-xml", "ros"])]
        format: String,
        /// One file; three for ros (cameras 1, 2, 3).
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Write the Calibration here instead of stdout.
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
    /// Writes a Calibration (JSON) in another tool's format: to OUTPUT (ros: OUTPUT's stem
    /// with _1, _2, _3 per camera), or stdout for a one-file format.
    Export {
        #[arg(long, value_parser = ["kalibr", "opencv-yaml", "opencv-xml", "ros"])]
        format: String,
        calibration: PathBuf,
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
}

#[derive(Args)]
struct CalibrateArgs {
    /// A CalibrationPattern in proto3 JSON (default: the two-board pattern, see README).
    #[arg(long)]
    pattern: Option<PathBuf>,
    /// The three images of the pattern, one per camera.
    #[arg(long, num_args = 3, value_names = ["IMG1", "IMG2", "IMG3"], required_unless_present = "correspondences")]
    images: Vec<PathBuf>,
    /// Correspondences in proto3 JSON (points_3d and three lists of points_2d), instead of
    /// images.
    #[arg(long, conflicts_with = "images")]
    correspondences: Option<PathBuf>,
    /// CalibrateOptions in proto3 JSON (e.g. {"distortion": true}).
    #[arg(long)]
    options: Option<PathBuf>,
    /// A Pose in proto3 JSON mapping pattern-frame points to the rig frame: the calibration
    /// is then in the rig frame. (`--rig-from-pattern`, its former name, still works.)
    #[arg(long, alias = "rig-from-pattern")]
    pattern_to_rig: Option<PathBuf>,
    /// Write the Calibration here instead of stdout.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

/// `trinocular serve`'s flags, the last of the configuration's layers: each names, by its
/// `serde` name, the configuration key it sets, and an absent flag sets nothing.
#[derive(Args, Serialize)]
struct ServeArgs {
    /// A TOML configuration file (see README); the environment (TRINOCULAR__SECTION__KEY)
    /// overrides it, and these flags override both.
    #[arg(long)]
    #[serde(skip)]
    config: Option<PathBuf>,
    /// gRPC listen address (default 0.0.0.0:50051).
    #[arg(long)]
    #[serde(rename = "server.grpc_addr", skip_serializing_if = "Option::is_none")]
    grpc_addr: Option<std::net::SocketAddr>,
    /// HTTP listen address (default 0.0.0.0:8080).
    #[arg(long)]
    #[serde(rename = "server.http_addr", skip_serializing_if = "Option::is_none")]
    http_addr: Option<std::net::SocketAddr>,
    /// Compute threads (default: one per core).
    #[arg(long)]
    #[serde(rename = "compute.threads", skip_serializing_if = "Option::is_none")]
    threads: Option<usize>,
    /// Jobs queued or running at once; past it, 429 / RESOURCE_EXHAUSTED (default: 2 per thread).
    #[arg(long)]
    #[serde(rename = "compute.max_jobs", skip_serializing_if = "Option::is_none")]
    max_jobs: Option<usize>,
    /// Largest request, MiB (default 32).
    #[arg(long)]
    #[serde(
        rename = "limits.max_message_mib",
        skip_serializing_if = "Option::is_none"
    )]
    max_message_mib: Option<usize>,
    /// Largest image, pixels (default 3,000,000).
    #[arg(long)]
    #[serde(
        rename = "limits.max_image_pixels",
        skip_serializing_if = "Option::is_none"
    )]
    max_image_pixels: Option<u64>,
    /// The compute jobs' working memory at once, MiB (default 320): each request reserves
    /// its estimate (36 bytes per image pixel, 512 per segment) before it runs.
    #[arg(long)]
    #[serde(
        rename = "limits.max_working_mib",
        skip_serializing_if = "Option::is_none"
    )]
    max_working_mib: Option<u64>,
    /// Most segments in one list of a request (default 100,000).
    #[arg(long)]
    #[serde(
        rename = "limits.max_segments_per_list",
        skip_serializing_if = "Option::is_none"
    )]
    max_segments_per_list: Option<usize>,
    /// Where sessions live: `embedded` (default: a file under --data-dir, no server needed),
    /// `memory` (in the process, gone when it stops) or `redis://HOST:PORT[/DB]` (shared by
    /// replicas).
    #[arg(long)]
    #[serde(rename = "store.url", skip_serializing_if = "Option::is_none")]
    store: Option<String>,
    /// The embedded store's directory (default `data`).
    #[arg(long)]
    #[serde(rename = "store.data_dir", skip_serializing_if = "Option::is_none")]
    data_dir: Option<PathBuf>,
    /// Sessions unused this long expire with their captures, seconds (default 86400).
    #[arg(long)]
    #[serde(
        rename = "store.session_ttl_s",
        skip_serializing_if = "Option::is_none"
    )]
    session_ttl_s: Option<u64>,
    /// Log one JSON object per line.
    #[arg(long)]
    #[serde(rename = "log.json", skip_serializing_if = "std::ops::Not::not")]
    log_json: bool,
    /// TLS on both ports: the server's certificate chain, PEM (with --tls-key).
    #[arg(long, requires = "tls_key")]
    #[serde(rename = "tls.cert_file", skip_serializing_if = "Option::is_none")]
    tls_cert: Option<PathBuf>,
    /// TLS on both ports: the certificate's private key, PEM (with --tls-cert).
    #[arg(long, requires = "tls_cert")]
    #[serde(rename = "tls.key_file", skip_serializing_if = "Option::is_none")]
    tls_key: Option<PathBuf>,
}

#[derive(Args)]
struct MatchArgs {
    /// A MatchRequest in proto3 JSON (instead of --calibration and --segments/--images).
    #[arg(conflicts_with_all = ["calibration", "segments", "images", "options"])]
    request: Option<PathBuf>,
    /// A Calibration in proto3 JSON.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// A SegmentTriplet in proto3 JSON.
    #[arg(long, requires = "calibration", conflicts_with = "images")]
    segments: Option<PathBuf>,
    /// Three image files (PNG, JPEG, PGM/PPM, TIFF, BMP), in camera order.
    #[arg(long, num_args = 3, value_names = ["IMG1", "IMG2", "IMG3"], requires = "calibration")]
    images: Option<Vec<PathBuf>>,
    /// MatchOptions in proto3 JSON.
    #[arg(long)]
    options: Option<PathBuf>,
    /// Write the MatchResponse here instead of stdout.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Image input: draw the three images side by side with their segments, matched ones
    /// coloured by 3D segment, unmatched ones grey (PNG).
    #[arg(long)]
    overlay: Option<PathBuf>,
    /// Also write the 3D segments (rig frame) as PLY, in their overlay colours.
    #[arg(long)]
    ply: Option<PathBuf>,
}

#[derive(Args)]
struct ExtractArgs {
    /// The image file.
    image: PathBuf,
    /// ExtractOptions in proto3 JSON.
    #[arg(long)]
    options: Option<PathBuf>,
    /// Write the SegmentList here instead of stdout.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

#[derive(Args)]
struct DemoArgs {
    /// Varies the room's furniture and albedos.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Directory for the images, overlay.png, top.png and response.json.
    #[arg(long, default_value = "demo")]
    out: PathBuf,
}

fn read(path: &Path) -> anyhow::Result<String> {
    fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

fn read_bytes(path: &Path) -> anyhow::Result<Vec<u8>> {
    fs::read(path).with_context(|| format!("cannot read {}", path.display()))
}

fn write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
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
impl From<api::RunError> for Failure {
    fn from(e: api::RunError) -> Self {
        match e {
            api::RunError::Input(e) => Failure::Input(e),
            stopped @ api::RunError::Stopped { .. } => Failure::Other(stopped.into()),
        }
    }
}
impl From<anyhow::Error> for Failure {
    fn from(e: anyhow::Error) -> Self {
        Failure::Other(e)
    }
}

fn build_request(args: &MatchArgs) -> Result<pb::MatchRequest, Failure> {
    if let Some(path) = &args.request {
        return Ok(api::match_request_from_json(&read(path)?)?);
    }
    let Some(calibration) = &args.calibration else {
        return Err(Failure::Other(anyhow::anyhow!(
            "give a REQUEST file, or --calibration with --segments or --images"
        )));
    };
    let input = match (&args.segments, &args.images) {
        (Some(segments), None) => {
            pb::match_request::Input::Segments(api::from_json("segments", &read(segments)?)?)
        }
        (None, Some(paths)) => pb::match_request::Input::Images(pb::ImageTriplet {
            images: paths
                .iter()
                .map(|p| {
                    Ok(pb::Image {
                        source: Some(pb::image::Source::Encoded(read_bytes(p)?)),
                    })
                })
                .collect::<anyhow::Result<_>>()?,
        }),
        _ => {
            return Err(Failure::Other(anyhow::anyhow!(
                "give --segments or --images with --calibration"
            )))
        }
    };
    let options = match &args.options {
        Some(path) => Some(api::from_json("options", &read(path)?)?),
        None => None,
    };
    Ok(pb::MatchRequest {
        calibration: Some(api::from_json("calibration", &read(calibration)?)?),
        options,
        input: Some(input),
    })
}

fn draw_overlay(input: &MatchInput, executed: &Executed, path: &Path) -> Result<(), Failure> {
    let (MatchSource::Images(images), Some(extracted)) = (&input.source, &executed.extracted)
    else {
        return Err(Failure::Other(anyhow::anyhow!(
            "--overlay needs image input (--images, or images in the request)"
        )));
    };
    let lists = [
        &extracted[0].segments,
        &extracted[1].segments,
        &extracted[2].segments,
    ];
    let labels = overlay::segment3_labels(&executed.output, lists.map(|l| l.segments.len()));
    let picture = overlay::triplet_overlay(
        [&images[0], &images[1], &images[2]],
        lists,
        [&labels[0], &labels[1], &labels[2]],
        input.rig.cameras().each_ref().map(|c| c.name()),
    );
    write(
        path,
        &picture.to_png().context("cannot encode the overlay")?,
    )?;
    Ok(())
}

fn run_match(args: &MatchArgs) -> Result<(), Failure> {
    let request = build_request(args)?;
    let input = api::match_request(&request, &api::RequestLimits::default())?;
    let executed = input.execute()?;
    if let Some(path) = &args.overlay {
        draw_overlay(&input, &executed, path)?;
    }
    let response = input.response(&executed);
    if let Some(path) = &args.ply {
        let ply = trinocular::map::export::segments_to_ply(&api::segments_3d_of(&response));
        write(path, ply.as_bytes())?;
    }
    let json = api::to_json(&response);
    match &args.output {
        Some(path) => write(path, (json + "\n").as_bytes())?,
        None => println!("{json}"),
    }
    Ok(())
}

fn run_calibration(command: &CalibrationCommand) -> Result<(), Failure> {
    use api::calibration_files::{export, import, CalibrationFormat};
    // An error about a file names the file the user passed, not its index.
    let named = |e: InputError, files: &[PathBuf]| -> Failure {
        let at = |i: usize| files.get(i).map(|p| p.display().to_string());
        let file = if let Some(rest) = e.field.strip_prefix("files[") {
            rest.split(']')
                .next()
                .and_then(|i| i.parse().ok())
                .and_then(at)
        } else if files.len() == 1 && !e.field.starts_with("calibration") && e.field != "files" {
            at(0)
        } else {
            None
        };
        match file {
            Some(f) => Failure::Input(InputError {
                field: format!("{f}: {}", e.field),
                message: e.message,
            }),
            None => Failure::Input(e),
        }
    };
    match command {
        CalibrationCommand::Import {
            format,
            files,
            output,
        } => {
            let format: CalibrationFormat = format.parse()?;
            let texts = files
                .iter()
                .map(|f| read(f))
                .collect::<anyhow::Result<Vec<_>>>()?;
            let refs: Vec<&str> = texts.iter().map(String::as_str).collect();
            let calibration = import(format, &refs).map_err(|e| named(e, files))?;
            let json = api::to_json(&calibration) + "\n";
            match output {
                Some(path) => write(path, json.as_bytes())?,
                None => print!("{json}"),
            }
        }
        CalibrationCommand::Export {
            format,
            calibration,
            output,
        } => {
            let format: CalibrationFormat = format.parse()?;
            let calibration: pb::Calibration = api::from_json("calibration", &read(calibration)?)?;
            let files = export(format, &calibration)?;
            match (output, files.len()) {
                (None, 1) => print!("{}", files[0]),
                (None, _) => {
                    return Err(Failure::Other(anyhow::anyhow!(
                        "{} writes one file per camera: give --output",
                        format.name()
                    )))
                }
                (Some(path), 1) => write(path, files[0].as_bytes())?,
                (Some(path), _) => {
                    let stem = path.with_extension("");
                    for (i, text) in files.iter().enumerate() {
                        let name = format!("{}_{}.yaml", stem.display(), i + 1);
                        write(Path::new(&name), text.as_bytes())?;
                        eprintln!("wrote {name}");
                    }
                }
            }
        }
    }
    Ok(())
}

fn run_pattern(args: &PatternArgs) -> Result<(), Failure> {
    let given: Option<pb::CalibrationPattern> = match &args.pattern {
        Some(path) => Some(api::from_json("pattern", &read(path)?)?),
        None => None,
    };
    let pattern = api::calibrate::pattern_from_pb(given.as_ref())?;
    fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    for (i, board) in pattern.boards.iter().enumerate() {
        let path = args.out.join(format!("board_{i}.svg"));
        write(&path, board.printable_svg(i).as_bytes())?;
        println!("{}", path.display());
    }
    Ok(())
}

fn run_calibrate(args: &CalibrateArgs) -> Result<(), Failure> {
    let json = |what: &str, path: &Option<PathBuf>| -> Result<Option<String>, Failure> {
        match path {
            Some(p) => Ok(Some(read(p).with_context(|| format!("--{what}"))?)),
            None => Ok(None),
        }
    };
    let input = match &args.correspondences {
        Some(path) => pb::calibrate_request::Input::Correspondences(api::from_json(
            "correspondences",
            &read(path)?,
        )?),
        None => pb::calibrate_request::Input::Images(pb::ImageTriplet {
            images: args
                .images
                .iter()
                .map(|p| {
                    Ok(pb::Image {
                        source: Some(pb::image::Source::Encoded(read_bytes(p)?)),
                    })
                })
                .collect::<anyhow::Result<_>>()?,
        }),
    };
    let request = pb::CalibrateRequest {
        pattern: match json("pattern", &args.pattern)? {
            Some(text) => Some(api::from_json("pattern", &text)?),
            None => None,
        },
        input: Some(input),
        pattern_to_rig: match json("pattern-to-rig", &args.pattern_to_rig)? {
            Some(text) => Some(api::from_json("pattern_to_rig", &text)?),
            None => None,
        },
        options: match json("options", &args.options)? {
            Some(text) => Some(api::from_json("options", &text)?),
            None => None,
        },
        camera_names: Vec::new(),
    };
    let response = api::calibrate::calibrate_request(&request, &DecodeLimits::default())?.run()?;
    for r in &response.reports {
        eprintln!(
            "{}: {} points, reprojection RMS {:.3} px, max {:.3} px",
            r.camera, r.points, r.rms_px, r.max_px
        );
    }
    let calibration = api::to_json(&response.calibration.unwrap_or_default());
    match &args.output {
        Some(path) => write(path, (calibration + "\n").as_bytes())?,
        None => println!("{calibration}"),
    }
    Ok(())
}

fn run_extract(args: &ExtractArgs) -> Result<(), Failure> {
    let bytes = read_bytes(&args.image)?;
    let image = decode::decode(&bytes, &DecodeLimits::default())
        .map_err(|e| InputError::new("image", e.to_string()))?;
    let options: Option<pb::ExtractOptions> = match &args.options {
        Some(path) => Some(api::from_json("options", &read(path)?)?),
        None => None,
    };
    let params = api::extract_params(options.as_ref());
    params
        .check()
        .map_err(|e| InputError::new(format!("options.{}", e.field()), e.to_string()))?;
    let extraction = trinocular::extract::extract(&image, None, &params);
    let json = api::to_json(&api::segment_list_to_pb(&extraction.segments));
    match &args.output {
        Some(path) => write(path, (json + "\n").as_bytes())?,
        None => println!("{json}"),
    }
    Ok(())
}

fn run_demo(args: &DemoArgs) -> Result<(), Failure> {
    let demo = trinocular::demo::run(args.seed).map_err(|e| Failure::Other(anyhow::anyhow!(e)))?;
    fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    for (v, png) in demo.images_png.iter().enumerate() {
        write(&args.out.join(format!("img{}.png", v + 1)), png)?;
    }
    write(&args.out.join("overlay.png"), &demo.overlay_png)?;
    write(&args.out.join("top.png"), &demo.top_png)?;
    write(
        &args.out.join("response.json"),
        (api::to_json(&demo.response) + "\n").as_bytes(),
    )?;
    write(
        &args.out.join("calibration.json"),
        (api::to_json(&demo.calibration) + "\n").as_bytes(),
    )?;
    println!("{}", demo.summary);
    println!(
        "wrote {0}/img1.png img2.png img3.png overlay.png top.png response.json calibration.json",
        args.out.display()
    );
    Ok(())
}

fn run_serve(args: &ServeArgs) -> Result<(), Failure> {
    use trinocular::service::{config::Config, serve::serve};
    let file = args.config.as_deref().map(read).transpose()?;
    let layers =
        Config::with_flags(Config::layers(file.as_deref()), args).map_err(anyhow::Error::from)?;
    let config = Config::from_layers(&layers).map_err(anyhow::Error::from)?;
    serve(config).map_err(anyhow::Error::from)?;
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Serve(args) => run_serve(args),
        Command::Demo(args) => run_demo(args),
        Command::Extract(args) => run_extract(args),
        Command::Match(args) => run_match(args),
        Command::Calibrate(args) => run_calibrate(args),
        Command::Calibration(command) => run_calibration(command),
        Command::Pattern(args) => run_pattern(args),
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// The defaults `serve --help` states are the configuration's own (it said 12,000,000
    /// pixels and 1024 MiB where the service used 3,000,000 and 320).
    #[test]
    fn serve_help_states_the_configured_defaults() {
        let mut command = Cli::command();
        let serve = command.find_subcommand_mut("serve").expect("serve");
        let help = serve.render_long_help().to_string();
        let limits = trinocular_server::config::Config::default().limits;
        let thousands = |n: u64| {
            let digits = n.to_string();
            let mut out = String::new();
            for (i, c) in digits.chars().enumerate() {
                if i > 0 && (digits.len() - i).is_multiple_of(3) {
                    out.push(',');
                }
                out.push(c);
            }
            out
        };
        for stated in [
            format!("(default {})", thousands(limits.max_image_pixels)),
            format!("(default {}):", limits.max_working_mib),
            format!("(default {})", limits.max_message_mib),
            format!(
                "(default {})",
                thousands(limits.max_segments_per_list as u64)
            ),
            "`memory`".to_string(),
        ] {
            assert!(help.contains(&stated), "{stated} not in:\n{help}");
        }
    }
}
