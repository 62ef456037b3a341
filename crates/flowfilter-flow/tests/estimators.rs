//! The estimators through the `FlowEstimator` seam: known synthetic motions of a textured image
//! (translation, rotation, zoom), forward-backward consistency, and bad input.

use flowfilter_flow::dis::{Dis, DisParams};
use flowfilter_flow::estimator::{forward_backward_mask, forward_backward_sparse};
use flowfilter_flow::lk::Gray;
use flowfilter_flow::{FlowError, FlowEstimator, FlowField, LucasKanade};
use flowfilter_geometry::Mask;

/// A band-limited texture.
fn texture(x: f32, y: f32) -> f32 {
    0.5 + 0.2 * (x * 0.21 + 0.3).sin() * (y * 0.17).cos()
        + 0.15 * ((x + 2.0 * y) * 0.093).sin()
        + 0.12 * ((3.0 * x - y) * 0.051).cos()
        + 0.1 * ((x - 1.7 * y) * 0.27).sin()
}

/// `from(x) = texture(x)`, `to(x) = texture(m^-1(x))`: content at `x` moves to `m(x)`.
fn pair(
    w: usize,
    h: usize,
    m: impl Fn(f32, f32) -> (f32, f32),
    inv: impl Fn(f32, f32) -> (f32, f32),
) -> (Gray, Gray, FlowField) {
    let a = Gray::from_fn(w, h, |x, y| texture(x as f32, y as f32));
    let b = Gray::from_fn(w, h, |x, y| {
        let (u, v) = inv(x as f32, y as f32);
        texture(u, v)
    });
    let mut truth = FlowField::zeros(w, h);
    for y in 0..h {
        for x in 0..w {
            let (mx, my) = m(x as f32, y as f32);
            *truth.flow.at_mut(x, y) = [mx - x as f32, my - y as f32];
        }
    }
    (a, b, truth)
}

/// Mean EPE over pixels at least `border` from the edge.
fn interior_epe(est: &FlowField, truth: &FlowField, border: usize) -> f64 {
    let (w, h) = truth.flow.dims();
    let mask = Mask::from_fn(w, h, |x, y| x >= border && y >= border && x + border < w && y + border < h);
    flowfilter_flow::metrics::epe(est, truth, Some(&mask)).unwrap().0
}

fn motions() -> Vec<(&'static str, (Gray, Gray, FlowField))> {
    let (w, h) = (240usize, 180usize);
    let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
    let th = 3f32.to_radians();
    let (c, s) = (th.cos(), th.sin());
    let z = 1.04f32;
    vec![
        ("translation", pair(w, h, |x, y| (x + 3.4, y - 1.7), |x, y| (x - 3.4, y + 1.7))),
        (
            "rotation",
            pair(
                w,
                h,
                move |x, y| (cx + c * (x - cx) - s * (y - cy), cy + s * (x - cx) + c * (y - cy)),
                move |x, y| (cx + c * (x - cx) + s * (y - cy), cy - s * (x - cx) + c * (y - cy)),
            ),
        ),
        (
            "zoom",
            pair(
                w,
                h,
                move |x, y| (cx + z * (x - cx), cy + z * (y - cy)),
                move |x, y| (cx + (x - cx) / z, cy + (y - cy) / z),
            ),
        ),
    ]
}

#[test]
fn dis_recovers_known_motions() {
    let dis = Dis::new(DisParams::medium()).unwrap();
    for (name, (a, b, truth)) in motions() {
        let est = dis.dense(&a, &b, None).unwrap();
        let e = interior_epe(&est, &truth, 16);
        println!("dis {name}: EPE {e:.4} px");
        assert!(e < 0.1, "{name}: EPE {e}");
    }
}

#[test]
fn lk_recovers_known_motions_sparse_and_dense() {
    // Two levels (at the third this small image is too flat to track) and an 11-px window (a
    // translation model over 21 px is biased by 0.15 px under a 3-degree rotation).
    let lk = LucasKanade { levels: 2, window: 11, min_eigen: 1e-5, ..LucasKanade::default() };
    for (name, (a, b, truth)) in motions() {
        let pts: Vec<[f32; 2]> =
            (0..8).flat_map(|i| (0..6).map(move |j| [40.0 + 22.0 * i as f32, 35.0 + 22.0 * j as f32])).collect();
        let tracked = lk.sparse(&a, &b, &pts, None).unwrap();
        let (mut sum, mut n) = (0.0, 0);
        for (p, f) in pts.iter().zip(&tracked) {
            // A window the tracker finds too flat is reported lost, never guessed.
            let Some(f) = f else { continue };
            let t = truth.at(p[0] as usize, p[1] as usize).unwrap();
            sum += ((f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2)).sqrt();
            n += 1;
        }
        assert!(n * 10 >= pts.len() * 9, "{name}: only {n} of {} tracked", pts.len());
        let sparse = sum / n as f32;
        let dense = interior_epe(&lk.dense(&a, &b, None).unwrap(), &truth, 24);
        println!("lk {name}: sparse EPE {sparse:.4}, dense EPE {dense:.4}");
        // LK's window model is a pure translation: exact for translations, biased under the
        // in-window shear of a rotation or zoom (documented limit; DIS meets 0.1 px there).
        let limit = if name == "translation" { 0.1 } else { 0.25 };
        assert!(f64::from(sparse) < limit && dense < limit, "{name}: {sparse} {dense}");
    }
}

#[test]
fn forward_backward_flags_inconsistent_flow() {
    let (a, b, _) = motions().remove(0).1;
    let dis = Dis::default();
    let (f, bk) = (dis.dense(&a, &b, None).unwrap(), dis.dense(&b, &a, None).unwrap());
    let ok = forward_backward_mask(&f, &bk, 0.5);
    let frac = ok.as_slice().iter().filter(|v| **v).count() as f64 / ok.as_slice().len() as f64;
    assert!(frac > 0.9, "consistent fraction {frac}");
    // A backward field that does not undo the forward one fails everywhere.
    let wrong = FlowField::zeros(a.width(), a.height());
    assert!(forward_backward_mask(&f, &wrong, 0.5).as_slice().iter().all(|v| !v));
    assert_eq!(
        forward_backward_sparse(
            &[Some([1.0, 0.0]), Some([1.0, 0.0]), None],
            &[Some([-1.0, 0.1]), Some([0.0, 0.0]), Some([0.0; 2])],
            0.5
        ),
        vec![true, false, false]
    );
}

#[test]
fn masks_limit_the_dense_output() {
    let (a, b, _) = motions().remove(0).1;
    let mask = Mask::from_fn(a.width(), a.height(), |x, _| x < 100);
    for est in [Box::new(Dis::default()) as Box<dyn FlowEstimator>, Box::new(LucasKanade::default())] {
        let f = est.dense(&a, &b, Some(&mask)).unwrap();
        assert!(f.valid.as_slice().iter().zip(mask.as_slice()).all(|(v, m)| !v || *m), "{}", est.name());
    }
}

#[test]
fn bad_input_gives_typed_errors() {
    let ok = Gray::filled(64, 48, 0.5);
    let estimators: Vec<Box<dyn FlowEstimator>> = vec![Box::new(Dis::default()), Box::new(LucasKanade::default())];
    for est in &estimators {
        let e = est.dense(&ok, &Gray::filled(32, 48, 0.5), None).unwrap_err();
        assert!(matches!(e, FlowError::SizeMismatch { from: (64, 48), to: (32, 48) }), "{e}");
        assert!(e.to_string().contains("sizes differ"));
        for (w, h) in [(0, 0), (1, 1), (64, 3)] {
            let tiny = Gray::filled(w, h, 0.5);
            let e = est.dense(&tiny, &tiny, None).unwrap_err();
            assert!(matches!(e, FlowError::TooSmall { which: "from", .. }), "{w}x{h}: {e}");
        }
        let e = est.sparse(&ok, &ok, &[[1.0, 1.0]], Some(&Mask::filled(10, 10, true))).unwrap_err();
        assert!(matches!(e, FlowError::MaskSize { .. }), "{e}");
    }
    for bad in [
        DisParams { patch_size: 2, ..DisParams::default() },
        DisParams { patch_stride: 0, ..DisParams::default() },
        DisParams { omega: 2.5, ..DisParams::default() },
        DisParams { finest_scale: 3, coarsest_scale: Some(1), ..DisParams::default() },
    ] {
        assert!(matches!(Dis::new(bad), Err(FlowError::Config(_))));
    }
    assert!(LucasKanade { window: 20, ..LucasKanade::default() }.validate().is_err());
}

#[test]
fn a_prediction_lets_lk_reach_displacements_its_pyramid_cannot() {
    let (w, h) = (260usize, 200usize);
    let (dx, dy) = (37.0f32, -21.0f32);
    let (a, b, _) = pair(w, h, move |x, y| (x + dx, y + dy), move |x, y| (x - dx, y - dy));
    let lk = LucasKanade { levels: 1, window: 15, min_eigen: 1e-5, ..LucasKanade::default() };
    let pts: Vec<[f32; 2]> =
        (0..5).flat_map(|i| (0..4).map(move |j| [60.0 + 30.0 * i as f32, 60.0 + 25.0 * j as f32])).collect();
    let err = |f: &[Option<[f32; 2]>]| {
        f.iter()
            .map(|v| v.map_or(f32::INFINITY, |v| ((v[0] - dx).powi(2) + (v[1] - dy).powi(2)).sqrt()))
            .fold(0.0f32, f32::max)
    };
    let plain = lk.sparse(&a, &b, &pts, None).unwrap();
    // A prediction 2-3 px off (as a geometric pose gives) is refined to the truth.
    let guesses = vec![[dx - 2.5, dy + 1.5]; pts.len()];
    let guided = lk.sparse_guided(&a, &b, &pts, &guesses, None).unwrap();
    println!("worst error: unguided {}, guided {}", err(&plain), err(&guided));
    assert!(err(&plain) > 5.0, "the unguided tracker should not reach a 42-px motion with one level");
    assert!(err(&guided) < 0.1, "guided worst error {}", err(&guided));
    assert!(matches!(lk.sparse_guided(&a, &b, &pts, &guesses[..3], None), Err(FlowError::Config(_))));
}

/// Lucas-Kanade offers a mode that matches each window's brightness, the one the pipeline uses
/// for tracks started from a wide-baseline guide: through the seam, it tracks a translated
/// texture darkened by 0.2 grey levels where plain windows are lost or wrong. DIS has no such
/// mode, and an estimator already in it offers none again.
#[test]
fn the_brightness_matched_estimator_tracks_through_an_exposure_change() {
    let (a, b, truth) = pair(128, 96, |x, y| (x + 3.4, y - 2.1), |x, y| (x - 3.4, y + 2.1));
    let darker = Gray::from_fn(128, 96, |x, y| *b.at(x, y) - 0.2);
    let pts: Vec<[f32; 2]> =
        (0..6).flat_map(|i| (0..4).map(move |j| [24.0 + 16.0 * i as f32, 24.0 + 16.0 * j as f32])).collect();
    let near_truth = |flow: Vec<Option<[f32; 2]>>| {
        flow.iter()
            .zip(&pts)
            .filter(|(f, p)| {
                let (Some(f), Some(t)) = (f, truth.at(p[0] as usize, p[1] as usize)) else { return false };
                (f[0] - t[0]).hypot(f[1] - t[1]) < 0.2
            })
            .count()
    };
    let lk = LucasKanade::turntable();
    let matched = lk.brightness_matched().expect("Lucas-Kanade has the mode");
    assert!(matched.brightness_matched().is_none(), "already in the mode");
    assert_eq!(near_truth(matched.sparse(&a, &darker, &pts, None).unwrap()), pts.len());
    assert!(near_truth(lk.sparse(&a, &darker, &pts, None).unwrap()) * 2 < pts.len());
    assert!(Dis::new(DisParams::medium()).unwrap().brightness_matched().is_none());
}
