//! `bench-speed`'s outputs: the rows (ours beside the peer, per thread count), `speed.json`,
//! `speed.md`, and the check CI runs.

use super::SpeedArgs;
use super::clouds::CloudPair;
use super::ours::{Timed, pose_errors};
use super::peers::PeerRow;
use super::pipeline::Throughput;
use crate::report::fmt;
use anyhow::Context;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// One timing of ours beside the peer's (registration or flow).
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// `registration` or `flow`.
    pub section: &'static str,
    /// Cloud pair (`wavy-N`) or Sintel case.
    pub case: String,
    /// Our method.
    pub method: String,
    /// Threads of both sides.
    pub threads: usize,
    /// Our fastest run, seconds.
    pub ours_s: f64,
    /// Our error: rotation (deg) or EPE (px).
    pub ours_error: f64,
    /// Our translation error (m), registration only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ours_translation_m: Option<f64>,
    /// Our iterations, registration only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ours_iterations: Option<usize>,
    /// The peer (library and version), when it ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peer: Option<String>,
    /// The peer's fastest run, seconds.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peer_s: Option<f64>,
    /// The peer's error, same unit as ours.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peer_error: Option<f64>,
    /// Peer time over ours (above 1: ours is faster).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speedup: Option<f64>,
    /// Whether the errors are against an exact truth (a synthetic pair) or a calibration's (a
    /// real pair, which the check does not hold ours to).
    pub exact_truth: bool,
    /// Registration: how far our pose is from the peer's (geodesic, deg).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub from_peer_deg: Option<f64>,
}

impl Row {
    /// A registration row; the peer's error is computed against the same truth.
    pub fn registration(pair: &CloudPair, method: &str, threads: usize, t: Timed, peer: Option<&PeerRow>) -> Self {
        let peer_pose = peer.and_then(|p| p.transform).and_then(|m| {
            let m = nalgebra::Matrix4::from_fn(|r, c| m[r][c]);
            flowfilter_pipeline::geometry::rigid_from_matrix(&m).ok()
        });
        let peer_error = peer_pose.map(|pose| pose_errors(&pose, &pair.truth).0);
        let apart = peer_pose.zip(t.pose).map(|(p, o)| pose_errors(&o, &p).0);
        let mut row = Self::new("registration", &pair.name, method, threads, t, peer, peer_error);
        (row.exact_truth, row.from_peer_deg) = (pair.exact_truth, apart);
        row
    }

    /// A flow row (errors are EPE over all pixels).
    pub fn flow(case: &str, threads: usize, t: Timed, peer: Option<&PeerRow>) -> Self {
        Self::new("flow", case, "dis-medium", threads, t, peer, peer.and_then(|p| p.epe))
    }

    fn new(
        section: &'static str,
        case: &str,
        method: &str,
        threads: usize,
        t: Timed,
        peer: Option<&PeerRow>,
        peer_error: Option<f64>,
    ) -> Self {
        Self {
            section,
            case: case.to_string(),
            method: method.to_string(),
            threads,
            ours_s: t.seconds,
            ours_error: t.error,
            ours_translation_m: t.translation_m,
            ours_iterations: t.iterations,
            peer: peer.map(|p| p.peer.clone()),
            peer_s: peer.map(|p| p.seconds),
            peer_error,
            speedup: peer.map(|p| p.seconds / t.seconds),
            exact_truth: true,
            from_peer_deg: None,
        }
    }
}

/// One pipeline method with one thread count.
#[derive(Debug, Clone, Serialize)]
pub struct PipelineRow {
    /// Method.
    pub method: String,
    /// Pool size (pairs run side by side).
    pub threads: usize,
    /// Pairs timed.
    pub pairs: usize,
    /// What was measured.
    #[serde(flatten)]
    pub throughput: Throughput,
    /// Each stream's own rate (the stream section; empty in the pipeline section).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub streams: Vec<super::stream::StreamRate>,
}

/// Everything `bench-speed` measured.
#[derive(Debug, Clone, Serialize)]
pub struct SpeedReport {
    /// The command's options, for the record.
    pub command: String,
    /// Source points of the registration pairs.
    pub sizes: Vec<usize>,
    /// Runs per timing (fastest kept): at least `repeats.min`, then more while under
    /// `repeats.budget_s` seconds in all.
    pub repeats: super::ours::Repeats,
    /// Registration and flow rows.
    pub rows: Vec<Row>,
    /// The pipeline's pairs.
    pub pipeline_pairs: String,
    /// Pipeline rows.
    pub pipeline: Vec<PipelineRow>,
    /// The streams' frames.
    pub stream_frames: String,
    /// Rows of the pipeline on the streams' consecutive frames.
    pub stream: Vec<PipelineRow>,
    /// What was skipped and why.
    pub notes: Vec<String>,
}

impl SpeedReport {
    /// An empty report for these options.
    pub fn new(args: &SpeedArgs, sizes: &[usize], repeats: super::ours::Repeats) -> Self {
        Self {
            command: format!("cargo xtask bench-speed {}", std::env::args().skip(2).collect::<Vec<_>>().join(" ")),
            sizes: sizes.to_vec(),
            repeats,
            rows: vec![],
            pipeline_pairs: String::new(),
            pipeline: vec![],
            stream_frames: String::new(),
            stream: vec![],
            notes: if args.no_peers { vec!["peers: not run (--no-peers)".into()] } else { vec![] },
        }
    }

    /// `speed.json` and `speed.md` into `dir`.
    pub fn write(&self, dir: &Path) -> anyhow::Result<()> {
        let json = dir.join("speed.json");
        std::fs::write(&json, serde_json::to_string_pretty(self)? + "\n")
            .with_context(|| format!("writing {}", json.display()))?;
        let md = dir.join("speed.md");
        std::fs::write(&md, self.markdown()).with_context(|| format!("writing {}", md.display()))
    }

    /// The tables.
    pub fn markdown(&self) -> String {
        let mut s = format!("# bench-speed\n\n`{}` ({})\n\n", self.command.trim(), self.repeats);
        for (section, unit) in [("registration", "deg"), ("flow", "EPE px")] {
            let rows: Vec<&Row> = self.rows.iter().filter(|r| r.section == section).collect();
            if rows.is_empty() {
                continue;
            }
            // Registration rows also say how far our pose is from the peer's.
            let apart = section == "registration";
            let _ = writeln!(
                s,
                "## {section}\n\n| case | method | threads | ours (s) | peer | peer (s) | speed-up | ours ({unit}) | peer ({unit}) |{}\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |{}",
                if apart { " ours from the peer (deg) |" } else { "" },
                if apart { " --- |" } else { "" },
            );
            for r in rows {
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {:.4} | {} | {} | {} | {:.4} | {} |{}",
                    r.case,
                    r.method,
                    r.threads,
                    r.ours_s,
                    r.peer.as_deref().unwrap_or("-"),
                    fmt(r.peer_s, 4),
                    r.speedup.map_or("-".into(), |x| format!("{x:.1}x")),
                    r.ours_error,
                    fmt(r.peer_error, 4),
                    if apart { format!(" {} |", fmt(r.from_peer_deg, 3)) } else { String::new() },
                );
            }
            s.push('\n');
        }
        if self.rows.iter().any(|r| !r.exact_truth) {
            s.push_str(
                "Real pairs (`real-*`): the errors are against the calibrated poses, themselves 0.5-1 deg off; \
                 the source starts moved by them.\n\n",
            );
        }
        if !self.pipeline.is_empty() {
            let _ = writeln!(s, "## pipeline (two frames in, pose out)\n\n{}\n", self.pipeline_pairs);
            pipeline_table(&mut s, &self.pipeline, "depth, both frames (ms)");
            s.push_str("\nStage times are per pair, with pairs side by side on the pool's threads.\n\n");
        }
        if !self.stream.is_empty() {
            let _ = writeln!(s, "## stream (consecutive frames, each prepared once)\n\n{}\n", self.stream_frames);
            pipeline_table(&mut s, &self.stream, "preparation, one frame (ms)");
            s.push_str(
                "\nPairs per second: the streams' wall time, every frame's preparation included. Stage times \
                 after the first are per pair, frames and pairs side by side on the pool's threads.\n\n",
            );
            stream_rates(&mut s, &self.stream);
        }
        for n in &self.notes {
            let _ = writeln!(s, "- {n}");
        }
        s
    }

    /// Every timing of ours finite and positive, every registration within 1 degree.
    pub fn check(&self) -> anyhow::Result<()> {
        if self.rows.is_empty() && self.pipeline.is_empty() && self.stream.is_empty() {
            anyhow::bail!("check: nothing was timed");
        }
        for r in &self.rows {
            if !(r.ours_s.is_finite() && r.ours_s > 0.0 && r.ours_error.is_finite()) {
                anyhow::bail!(
                    "check: {} {} {} threads: time {} error {}",
                    r.case,
                    r.method,
                    r.threads,
                    r.ours_s,
                    r.ours_error
                );
            }
            if r.section == "registration" && r.exact_truth && r.ours_error > 1.0 {
                anyhow::bail!(
                    "check: {} {} {} threads ends {:.3} deg from the truth",
                    r.case,
                    r.method,
                    r.threads,
                    r.ours_error
                );
            }
        }
        for r in self.pipeline.iter().chain(&self.stream) {
            let t = &r.throughput;
            if !(t.pairs_per_second.is_finite() && t.pairs_per_second > 0.0 && t.mean_rotation_deg.is_finite()) {
                anyhow::bail!("check: pipeline {} {} threads: {t:?}", r.method, r.threads);
            }
        }
        Ok(())
    }
}

/// The rows of a pipeline table (header included); `first_stage` names the first stage column.
fn pipeline_table(s: &mut String, rows: &[PipelineRow], first_stage: &str) {
    let _ = writeln!(
        s,
        "| method | threads | pairs/s | mean rotation error (deg) | success | {first_stage} | flow (ms) | correspondences (ms) | registration (ms) | judge (ms) | align (ms) |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    for r in rows {
        let t = &r.throughput;
        let _ = writeln!(
            s,
            "| {} | {} | {:.2} | {:.3} | {:.0}% | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |",
            r.method,
            r.threads,
            t.pairs_per_second,
            t.mean_rotation_deg,
            100.0 * t.success,
            t.stage_ms[0],
            t.stage_ms[1],
            t.stage_ms[2],
            t.stage_ms[3],
            t.stage_ms[4],
            t.stage_ms[5]
        );
    }
}

/// Each row's slowest and fastest stream (pairs per second).
fn stream_rates(s: &mut String, rows: &[PipelineRow]) {
    let _ = writeln!(
        s,
        "| method | threads | slowest stream (pairs/s) | fastest stream (pairs/s) |\n| --- | --- | --- | --- |"
    );
    for r in rows {
        let by_rate = |a: &&super::stream::StreamRate, b: &&super::stream::StreamRate| {
            a.pairs_per_second.total_cmp(&b.pairs_per_second)
        };
        let (Some(slow), Some(fast)) = (r.streams.iter().min_by(by_rate), r.streams.iter().max_by(by_rate)) else {
            continue;
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} {:.2} | {} {:.2} |",
            r.method, r.threads, slow.object, slow.pairs_per_second, fast.object, fast.pairs_per_second
        );
    }
    s.push('\n');
}
