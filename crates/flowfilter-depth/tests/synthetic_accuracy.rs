//! The depth stage against the synthesiser's ground truth.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::filter::{bigbird_discontinuity, gaussian_window, metric_depth};
use flowfilter_depth::{
    DepthConfig, DepthStage, GaussianFilterConfig, InterpolationMethod, RegistrationMethod, WindowEstimator,
};
use flowfilter_geometry::{DepthMap, Mask};
use flowfilter_synth::{NoiseProfile, RenderedFrame, Rig, Scene, procedural, render_frame};

fn np(c: u8) -> SensorId {
    SensorId::new(c).unwrap()
}

/// Mask pixels more than `margin` pixels from an edge: the mask's boundary, or a depth
/// discontinuity of the true depth (a step of more than 1 cm between neighbours, where the
/// object occludes itself and the depth camera, 2.5 cm away, sees a different surface).
fn interior(mask: &Mask, truth: &DepthMap, margin: usize) -> Vec<usize> {
    let (w, h) = mask.dims();
    let z = truth.as_slice();
    let edge: Vec<bool> = (0..w * h)
        .map(|k| {
            let (x, y) = (k % w, k / w);
            !mask.as_slice()[k]
                || (x + 1 < w && (z[k] - z[k + 1]).abs() > 0.01)
                || (y + 1 < h && (z[k] - z[k + w]).abs() > 0.01)
        })
        .collect();
    let m = margin as isize;
    (0..w * h)
        .filter(|&k| {
            let (x, y) = ((k % w) as isize, (k / w) as isize);
            (-m..=m).all(|dy| {
                (-m..=m).all(|dx| {
                    let (nx, ny) = (x + dx, y + dy);
                    nx >= 0 && ny >= 0 && nx < w as isize && ny < h as isize && !edge[ny as usize * w + nx as usize]
                })
            })
        })
        .collect()
}

fn frames(noise: Option<&NoiseProfile>) -> Vec<(String, Rig, RenderedFrame)> {
    let rig = Rig::bigbird_like();
    let mut out = vec![];
    for (name, seed) in [("box", 1u64), ("can", 2), ("bottle", 3)] {
        let scene = Scene::new(procedural(name, seed).unwrap().placed_on_table(0.01, -0.005), seed);
        for (c, angle) in [(1u8, 0u32), (3, 45), (5, 120)] {
            out.push((
                format!("{name} NP{c}@{angle}"),
                rig.clone(),
                render_frame(&scene, &rig, np(c), angle, noise, seed),
            ));
        }
    }
    out
}

fn accuracy(config: DepthConfig, label: &str) -> f64 {
    let stage = DepthStage::new(config).unwrap();
    let (mut good, mut total) = (0usize, 0usize);
    for (name, rig, f) in frames(None) {
        let rgbd = rig.sensors[&f.id.sensor].rgbd;
        let out = stage.process(&f.raw_depth, &f.color, &f.mask, &rgbd).unwrap();
        let pixels = interior(&f.mask, &f.color_depth, 3);
        let ok = pixels
            .iter()
            .filter(|&&k| {
                let (z, t) = (out.depth.as_slice()[k], f.color_depth.as_slice()[k]);
                z > 0.0 && (z - t).abs() < 1e-3
            })
            .count();
        println!(
            "{label}: {name}: {ok}/{} interior mask pixels within 1 mm ({:.3}%)",
            pixels.len(),
            100.0 * ok as f64 / pixels.len() as f64
        );
        good += ok;
        total += pixels.len();
    }
    good as f64 / total as f64
}

#[test]
fn registered_and_interpolated_depth_matches_the_colour_cameras_true_depth() {
    let frac = accuracy(DepthConfig::default(), "mesh + linear");
    println!("mesh + linear: {:.4}% of all interior mask pixels within 1 mm", 100.0 * frac);
    assert!(frac >= 0.99, "{frac}");
    let mut splat = DepthConfig::default();
    splat.registration.method = RegistrationMethod::Splat;
    splat.interpolation.method = InterpolationMethod::Linear;
    // For comparison only: splatting lets the table behind show through the gaps between
    // splatted object samples, which interpolation then spreads.
    let frac = accuracy(splat, "splat + linear");
    println!("splat + linear: {:.4}% within 1 mm", 100.0 * frac);
}

#[test]
fn edge_filters_remove_flying_pixels_and_keep_valid_ones() {
    let profile = NoiseProfile::carmine();
    let mut rows = vec![];
    let paper = GaussianFilterConfig { estimator: WindowEstimator::MeanStd, ..Default::default() };
    let robust = GaussianFilterConfig::default();
    let variants: [(&str, bool, Option<GaussianFilterConfig>, bool); 6] = [
        ("gaussian mean/std (paper) + step 3x3/15mm", false, Some(paper.clone()), true),
        ("bigbird 7x7/10cm", true, None, false),
        ("gaussian mean/std (paper)", false, Some(paper.clone()), false),
        ("gaussian robust", false, Some(robust.clone()), false),
        ("step 3x3/15mm", false, None, true),
        ("gaussian robust + step 3x3/15mm (default)", false, Some(robust), true),
    ];
    for (label, bigbird, gaussian, step) in variants {
        let (mut flying, mut flying_removed, mut valid, mut valid_kept) = (0usize, 0usize, 0usize, 0usize);
        for (_, rig, f) in frames(Some(&profile)) {
            let unit = rig.sensors[&f.id.sensor].rgbd.metres_per_unit;
            let mut d = metric_depth(&f.raw_depth, unit);
            if bigbird {
                d = bigbird_discontinuity(&d, 7, 0.1).0;
            }
            if let Some(g) = &gaussian {
                d = gaussian_window(&d, g).0;
            }
            if step {
                d = bigbird_discontinuity(&d, 3, 0.015).0;
            }
            for k in 0..d.as_slice().len() {
                if f.raw_depth.as_slice()[k] == 0 {
                    continue;
                }
                let kept = d.as_slice()[k] > 0.0;
                if f.noise_truth.flying.as_slice()[k] {
                    flying += 1;
                    flying_removed += usize::from(!kept);
                } else {
                    valid += 1;
                    valid_kept += usize::from(kept);
                }
            }
        }
        let (removed, kept) = (flying_removed as f64 / flying as f64, valid_kept as f64 / valid as f64);
        println!(
            "{label}: removed {:.2}% of {flying} flying pixels, kept {:.2}% of {valid} valid pixels",
            100.0 * removed,
            100.0 * kept
        );
        rows.push((label, removed, kept));
    }
    let (_, removed, kept) = rows[5];
    assert!(removed >= 0.95 && kept >= 0.95, "default filter chain: removed {removed}, kept {kept}");
}
