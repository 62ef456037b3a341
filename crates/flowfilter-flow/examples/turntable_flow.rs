//! Flow accuracy on the task's own domain: synthesised turntable pairs (Carmine colour noise)
//! with exact ground truth from `flowfilter_synth::true_flow`, for the procedural objects and,
//! when `../shared/data/ycb` is present, the YCB scans. Scores non-occluded object pixels.
//! `cargo run --release -p flowfilter-flow [--features onnx] --example turntable_flow [-- STEPS] [CAMERAS] [OBJECTS]`
//! (defaults `3,9,15`, `NP1,NP3,NP5` and every object; base angle 0). DIS runs with
//! central-difference search gradients, as the pipeline configures it. With the `onnx` feature the
//! table has a column for our network (`net`, crates/flowfilter-flow/models/ffnet.onnx).

use flowfilter_bigbird::{FrameId, SensorId};
use flowfilter_flow::dis::{Dis, DisParams, SearchGradients};
use flowfilter_flow::lk::to_gray;
use flowfilter_flow::metrics::{epe, epe_at_points};
use flowfilter_flow::{FlowEstimator, FlowField, LucasKanade};
use flowfilter_geometry::Mask;
use flowfilter_synth::{NoiseProfile, Rig, Scene, TexturedMesh, procedural, render_frame, true_flow};
use std::path::Path;
use std::time::Instant;

fn main() {
    let arg = |i: usize, default: &str| std::env::args().nth(i).unwrap_or_else(|| default.to_string());
    let steps: Vec<u32> = arg(1, "3,9,15").split(',').map(|s| s.parse().expect("step")).collect();
    let cameras: Vec<SensorId> = arg(2, "NP1,NP3,NP5").split(',').map(|s| s.parse().expect("camera")).collect();
    let only: Option<Vec<String>> = std::env::args().nth(3).map(|a| a.split(',').map(str::to_string).collect());
    let mut objects: Vec<(String, TexturedMesh)> = ["box", "can", "bottle"]
        .iter()
        .filter(|n| only.as_ref().is_none_or(|o| o.iter().any(|x| x == *n)))
        .map(|n| (format!("procedural {n}"), procedural(n, 1).expect("known")))
        .collect();
    let ycb = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/ycb");
    match std::fs::read_dir(&ycb) {
        Ok(dir) => {
            let mut names: Vec<String> = dir
                .flatten()
                .filter(|e| e.path().join("textured.obj").is_file())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            for n in names.into_iter().filter(|n| only.as_ref().is_none_or(|o| o.contains(n))) {
                let mesh = TexturedMesh::load_obj(ycb.join(&n).join("textured.obj")).expect("YCB mesh");
                objects.push((n, mesh));
            }
        }
        Err(_) => eprintln!("{} is absent: procedural objects only", ycb.display()),
    }
    let rig = Rig::bigbird_like();
    let noise = NoiseProfile::carmine();
    // Central-difference patch search: the pipeline configuration's setting for these pairs
    // (OpenCV's damped Sobel steps, the presets' default, reach large motions more slowly).
    let central =
        |p: DisParams| Dis::new(DisParams { search_gradients: SearchGradients::Central, ..p }).expect("valid");
    let (dis_fast, dis_medium) = (central(DisParams::fast()), central(DisParams::medium()));
    let lk = LucasKanade::default();
    #[cfg(feature = "onnx")]
    let net = flowfilter_flow::net::ffnet().expect("shipped network");
    println!(
        "| object | pairs | occluded % | DIS-fast EPE | DIS-medium EPE | LK EPE (8-px grid) | DIS-medium ms | net EPE | net ms |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    let mut totals = [0.0f64; 6];
    let mut count = 0usize;
    for (name, mesh) in objects {
        let scene = Scene::new(mesh.placed_on_table(0.01, -0.005), 1);
        let mut sums = [0.0f64; 7];
        let mut pairs = 0usize;
        for &camera in &cameras {
            for &step in &steps {
                let (from, to) = (FrameId { sensor: camera, angle: 0 }, FrameId { sensor: camera, angle: step });
                let truth = true_flow(&scene, &rig, from, to, 0.003);
                let gt = FlowField { flow: truth.flow.clone(), valid: truth.visible.clone() };
                let a = render_frame(&scene, &rig, camera, 0, Some(&noise), 1);
                let b = render_frame(&scene, &rig, camera, step, Some(&noise), 1);
                let (ga, gb) = (to_gray(&a.color), to_gray(&b.color));
                let t = Instant::now();
                let medium = dis_medium.dense(&ga, &gb, None).expect("flow");
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let fast = dis_fast.dense(&ga, &gb, None).expect("flow");
                let visible: &Mask = &truth.visible;
                let grid: Vec<[usize; 2]> = (0..gt.height())
                    .step_by(8)
                    .flat_map(|y| (0..gt.width()).step_by(8).map(move |x| [x, y]))
                    .filter(|&[x, y]| *visible.at(x, y))
                    .collect();
                let pts: Vec<[f32; 2]> = grid.iter().map(|&[x, y]| [x as f32, y as f32]).collect();
                let tracked = lk.sparse(&ga, &gb, &pts, None).expect("lk");
                let sparse: Vec<([usize; 2], Option<[f32; 2]>)> = grid.iter().copied().zip(tracked).collect();
                let (Some(f), Some(m), Some(l)) =
                    (epe(&fast, &gt, None), epe(&medium, &gt, None), epe_at_points(&sparse, &gt))
                else {
                    continue;
                };
                sums[0] += 100.0 * truth.occluded_fraction();
                sums[1] += f.0;
                sums[2] += m.0;
                sums[3] += l.0;
                sums[4] += ms;
                #[cfg(feature = "onnx")]
                {
                    let t = Instant::now();
                    let f = net.dense(&ga, &gb, None).expect("net");
                    sums[6] += t.elapsed().as_secs_f64() * 1e3;
                    sums[5] += epe(&f, &gt, None).map_or(f64::NAN, |e| e.0);
                }
                pairs += 1;
            }
        }
        if pairs == 0 {
            continue;
        }
        let n = pairs as f64;
        let net_cols =
            if cfg!(feature = "onnx") { format!("{:.3} | {:.0}", sums[5] / n, sums[6] / n) } else { "- | -".into() };
        println!(
            "| {name} | {pairs} | {:.1} | {:.3} | {:.3} | {:.3} | {:.0} | {net_cols} |",
            sums[0] / n,
            sums[1] / n,
            sums[2] / n,
            sums[3] / n,
            sums[4] / n
        );
        for i in [0, 1, 2, 3, 5] {
            totals[i] += sums[i];
        }
        count += pairs;
    }
    let n = count.max(1) as f64;
    let net_all = if cfg!(feature = "onnx") { format!("{:.3}", totals[5] / n) } else { "-".into() };
    println!(
        "| **all** | {count} | {:.1} | {:.3} | {:.3} | {:.3} | | {net_all} | |",
        totals[0] / n,
        totals[1] / n,
        totals[2] / n,
        totals[3] / n
    );
}
