//! `flowfilter inspect <object-dir>`.

use clap::Args;
use flowfilter_bigbird::{InspectReport, inspect};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

/// Arguments of `inspect`.
#[derive(Args)]
pub struct InspectArgs {
    /// The object directory (holding calibration.h5, NP<c>_<angle>.h5/.jpg, masks/, poses/).
    pub object_dir: PathBuf,
}

/// Run `inspect`: print the summary to stdout, every problem to stderr; exit 1 on any problem.
pub fn run(args: &InspectArgs) -> anyhow::Result<ExitCode> {
    tracing::info!(dir = %args.object_dir.display(), "inspecting");
    let report = inspect(&args.object_dir);
    print!("{}", summary_text(&report));
    if report.is_ok() {
        println!("OK: no problems found");
        return Ok(ExitCode::SUCCESS);
    }
    eprintln!("{} problem(s) found:", report.problems.len());
    for p in &report.problems {
        eprintln!("  - {p}");
    }
    Ok(ExitCode::FAILURE)
}

fn sizes(set: Option<&std::collections::BTreeSet<(u32, u32)>>) -> String {
    set.map(|s| s.iter().map(|(w, h)| format!("{w}x{h}")).collect::<Vec<_>>().join(", ")).unwrap_or_else(|| "-".into())
}

/// The human-readable summary of a report.
fn summary_text(report: &InspectReport) -> String {
    let s = &report.summary;
    let mut out = String::new();
    let _ = writeln!(out, "object:  {}", s.dir.display());
    let angles: Vec<u32> = s.angles().into_iter().collect();
    let angle_text = match (angles.first(), angles.last()) {
        (Some(a), Some(b)) => format!("{} angles ({a}..{b} deg)", angles.len()),
        _ => "no angles".into(),
    };
    let _ = writeln!(
        out,
        "frames:  {} found, {} valid; {}; {} table poses",
        s.frames.len(),
        s.valid_frames,
        angle_text,
        s.table_poses.len()
    );
    for sensor in s.sensors() {
        let n = s.frames.iter().filter(|f| f.sensor == sensor).count();
        let _ = write!(
            out,
            "{sensor}:     {n} frames, colour {}, depth {}",
            sizes(s.color_sizes.get(&sensor)),
            sizes(s.depth_sizes.get(&sensor))
        );
        if let Some(c) = s.calibration.as_ref().and_then(|c| c.sensors.get(&sensor)) {
            let k = c.rgb_k;
            let d = c.depth_k;
            let t = c.color_from_depth().translation.vector;
            let _ = write!(
                out,
                "\n         rgb fx={:.2} fy={:.2} cx={:.2} cy={:.2} dist={:?}\n         depth fx={:.2} fy={:.2} cx={:.2} cy={:.2} ({}), depth scale {:.5} (bias {}), rgb<-ir offset ({:.4}, {:.4}, {:.4}) m",
                k.fx,
                k.fy,
                k.cx,
                k.cy,
                c.rgb_d.to_array(),
                d.fx,
                d.fy,
                d.cx,
                d.cy,
                c.depth_k_key,
                c.ir_depth_scale,
                c.ir_depth_bias,
                t.x,
                t.y,
                t.z
            );
            if let Some(note) = c.depth_bias_note(sensor) {
                let _ = write!(out, "\n         note: {note}");
            }
        }
        out.push('\n');
    }
    if let Some(c) = &s.calibration {
        let _ = writeln!(out, "calibration: {} Carmine sensor(s), {} Canon camera(s)", c.sensors.len(), c.canon.len());
    }
    if let Some(t) = &s.turntable {
        let _ = writeln!(
            out,
            "turntable: centre ({:.4}, {:.4}, {:.4}) m, normal ({:.4}, {:.4}, {:.4})",
            t.center.x, t.center.y, t.center.z, t.normal.x, t.normal.y, t.normal.z
        );
    }
    out
}
