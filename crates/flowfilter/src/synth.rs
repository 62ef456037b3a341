//! `flowfilter synth`: render a turntable capture in the BigBIRD layout.

use anyhow::Context;
use clap::Args;
use flowfilter_bigbird::SensorId;
use flowfilter_synth::{
    CaptureOptions, NoiseProfile, Rig, Scene, TexturedMesh, contact_sheet, parse_angles, procedural, render_frame,
    write_capture,
};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

/// The object to render (shared by `synth` and `truth-flow`).
#[derive(Args)]
#[command(group(clap::ArgGroup::new("object").required(true).args(["mesh", "procedural"])))]
pub struct ObjectArgs {
    /// A textured, triangulated OBJ (with MTL and diffuse texture), in metres, z up.
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    /// A procedural object.
    #[arg(long, value_parser = clap::builder::PossibleValuesParser::new(flowfilter_synth::PROCEDURAL_NAMES))]
    pub procedural: Option<String>,
    /// Seed of all randomness (textures of procedural objects, noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Offset of the object from the turntable centre, metres, `dx,dy`.
    #[arg(long, default_value = "0.01,-0.005", value_delimiter = ',', num_args = 2, allow_hyphen_values = true)]
    pub offset: Vec<f32>,
}

impl ObjectArgs {
    /// The object on the turntable.
    pub fn scene(&self) -> anyhow::Result<Scene> {
        let mesh = match (&self.mesh, &self.procedural) {
            (Some(path), _) => TexturedMesh::load_obj(path)?,
            (None, Some(name)) => procedural(name, self.seed)?,
            (None, None) => unreachable!("clap requires one of --mesh and --procedural"),
        };
        let mesh = mesh.placed_on_table(self.offset[0], self.offset[1]);
        tracing::info!(source = %mesh.source.display(), triangles = mesh.triangles.len(), "loaded object");
        Ok(Scene::new(mesh, self.seed))
    }
}

/// Arguments of `synth`.
#[derive(Args)]
pub struct SynthArgs {
    /// The object.
    #[command(flatten)]
    pub object: ObjectArgs,
    /// Output object directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Sensors to render, comma separated.
    #[arg(long, default_value = "NP1,NP2,NP3,NP4,NP5", value_delimiter = ',')]
    pub cameras: Vec<String>,
    /// Turntable angles: start:end:step (inclusive), a comma list, or one angle.
    #[arg(long, default_value = "0:357:3")]
    pub angles: String,
    /// Noise profile: `carmine` (built in), `none` (exact data), or a TOML profile file.
    #[arg(long, default_value = "carmine")]
    pub noise: String,
    /// Also write a contact sheet PNG (colour, mask, depth) of the first angle of every camera.
    #[arg(long)]
    pub contact_sheet: Option<PathBuf>,
}

/// Run `synth`.
pub fn run(args: &SynthArgs) -> anyhow::Result<ExitCode> {
    let sensors: Vec<SensorId> = args
        .cameras
        .iter()
        .map(|c| c.trim().parse::<SensorId>().map_err(anyhow::Error::msg))
        .collect::<Result<_, _>>()?;
    let angles = parse_angles(&args.angles)?;
    let noise = NoiseProfile::resolve(&args.noise)?;
    let scene = args.object.scene()?;
    let rig = Rig::bigbird_like();
    let opts = CaptureOptions {
        sensors: sensors.clone(),
        angles: angles.clone(),
        noise: noise.clone(),
        seed: args.object.seed,
    };
    let total = sensors.len() * angles.len();
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} frames, {elapsed}, eta {eta}")
            .expect("valid template"),
    );
    bar.set_message(format!("synth {}", args.out.display()));
    let start = Instant::now();
    write_capture(&args.out, &scene, &rig, &opts, &|done, _| bar.set_position(done as u64))
        .with_context(|| format!("writing {}", args.out.display()))?;
    bar.finish();
    let secs = start.elapsed().as_secs_f64();
    println!(
        "wrote {} frames ({} camera(s) x {} angle(s)) to {} in {:.1} s ({:.3} s/frame, noise: {})",
        total,
        sensors.len(),
        angles.len(),
        args.out.display(),
        secs,
        secs / total.max(1) as f64,
        noise.as_ref().map_or("none", |p| p.name.as_str())
    );
    if let Some(png) = &args.contact_sheet {
        let frames: Vec<_> = sensors
            .iter()
            .map(|&s| render_frame(&scene, &rig, s, angles[0], noise.as_ref(), args.object.seed))
            .collect();
        let unit = rig.sensors[&sensors[0]].rgbd.metres_per_unit;
        contact_sheet(&frames.iter().collect::<Vec<_>>(), unit)
            .save(png)
            .with_context(|| format!("writing {}", png.display()))?;
        println!("contact sheet: {}", png.display());
    }
    Ok(ExitCode::SUCCESS)
}
