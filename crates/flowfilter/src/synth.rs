//! `flowfilter synth`: render a turntable capture in the BigBIRD layout, or scenes in the BOP
//! layout (one scene per camera, depth registered to colour).

use anyhow::Context;
use clap::Args;
use flowfilter_bigbird::SensorId;
use flowfilter_synth::{
    BopSceneOptions, CaptureOptions, FrameEffects, NoiseProfile, Rig, Scene, TexturedMesh, contact_sheet, parse_angles,
    parse_fractional_angles, procedural, render_frame, write_bop_scene, write_capture,
};
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
    #[arg(long, default_value = "0.01,-0.005", allow_hyphen_values = true, value_parser = crate::args::offset_pair)]
    pub offset: [f32; 2],
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
    /// Output: the object directory (BigBIRD), or the split folder that receives one scene folder
    /// per camera, named by the camera's number (`000003` for NP3) (BOP).
    #[arg(long)]
    pub out: PathBuf,
    /// Layout to write.
    #[arg(long, value_enum, default_value_t = Format::Bigbird)]
    pub format: Format,
    /// Sensors to render, comma separated.
    #[arg(long, default_value = "NP1,NP2,NP3,NP4,NP5", value_delimiter = ',')]
    pub cameras: Vec<String>,
    /// Turntable angles: start:end:step (inclusive), a comma list, or one angle (whole degrees
    /// for BigBIRD; fractions allowed for BOP, e.g. `0:2.5:0.25`). BOP image ids follow them.
    #[arg(long, default_value = "0:357:3")]
    pub angles: String,
    /// BOP: the object's id in `scene_gt.json`.
    #[arg(long, default_value_t = 1)]
    pub obj_id: u32,
    /// BOP: millimetres per depth unit (`depth_scale` of `scene_camera.json`).
    #[arg(long, default_value_t = 0.1, value_parser = crate::args::positive_f64)]
    pub depth_scale_mm: f64,
    /// BOP: per-frame effects of real captures (`real`: exposure +-12%, white balance +-4%,
    /// masks up to 2 px off and 2 px too large or small, depth up to 0.1 deg of rotation away
    /// from colour; `none`: exact).
    #[arg(long, value_enum, default_value_t = Effects::Real)]
    pub effects: Effects,
    /// Noise profile: `carmine`, `xtion-sample` or `sr300-shelf` (built in), `none` (exact
    /// data), or a TOML profile file.
    #[arg(long, default_value = "carmine")]
    pub noise: String,
    /// Also write a contact sheet PNG (colour, mask, depth) of the first angle of every camera.
    #[arg(long)]
    pub contact_sheet: Option<PathBuf>,
}

/// The dataset layouts `synth` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// The BigBIRD object layout (separate depth camera, HDF5 depth, turntable poses).
    Bigbird,
    /// The BOP scene layout (depth registered to colour, visible masks, scene_gt.json).
    Bop,
}

/// Per-frame effects of real captures (BOP).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Effects {
    /// [`FrameEffects::REAL_SENSOR`].
    Real,
    /// [`FrameEffects::NONE`].
    None,
}

/// Run `synth`.
pub fn run(args: &SynthArgs) -> anyhow::Result<ExitCode> {
    let sensors: Vec<SensorId> = args
        .cameras
        .iter()
        .map(|c| c.trim().parse::<SensorId>().map_err(anyhow::Error::msg))
        .collect::<Result<_, _>>()?;
    if args.format == Format::Bop {
        return run_bop(args, &sensors);
    }
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
    let bar = crate::progress::bar(total, "frames");
    bar.set_message(format!("synth {}", args.out.display()));
    let start = Instant::now();
    write_capture(&args.out, &scene, &rig, &opts, &|done, _| crate::progress::advance(&bar, done))
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
        crate::save_image(&contact_sheet(&frames.iter().collect::<Vec<_>>(), unit), png)?;
        println!("contact sheet: {}", png.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// `synth --format bop`: one BOP scene folder per camera.
fn run_bop(args: &SynthArgs, sensors: &[SensorId]) -> anyhow::Result<ExitCode> {
    let opts = BopSceneOptions {
        angles_deg: parse_fractional_angles(&args.angles)?,
        noise: NoiseProfile::resolve(&args.noise)?,
        effects: match args.effects {
            Effects::Real => FrameEffects::REAL_SENSOR,
            Effects::None => FrameEffects::NONE,
        },
        seed: args.object.seed,
        obj_id: args.obj_id,
        depth_scale_mm: args.depth_scale_mm,
    };
    let scene = args.object.scene()?;
    let rig = Rig::bigbird_like();
    let total = sensors.len() * opts.angles_deg.len();
    let bar = crate::progress::bar(total, "images");
    let start = Instant::now();
    for (k, sensor) in sensors.iter().enumerate() {
        let dir = args.out.join(format!("{:06}", sensor.index()));
        bar.set_message(format!("synth {}", dir.display()));
        let base = k * opts.angles_deg.len();
        write_bop_scene(&dir, &scene, &rig.sensors[sensor], &opts, &|done, _| {
            crate::progress::advance(&bar, base + done)
        })
        .with_context(|| format!("writing {}", dir.display()))?;
    }
    bar.finish();
    println!(
        "wrote {} BOP scene(s) of {} image(s) (object {}, depth_scale {} mm, noise: {}, effects: {:?}) to {} in {:.1} s",
        sensors.len(),
        opts.angles_deg.len(),
        opts.obj_id,
        opts.depth_scale_mm,
        opts.noise.as_ref().map_or("none", |p| p.name.as_str()),
        args.effects,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(ExitCode::SUCCESS)
}
