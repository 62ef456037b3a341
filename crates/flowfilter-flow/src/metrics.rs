//! End-point error.

use crate::FlowField;
use flowfilter_geometry::Mask;

/// Mean end-point error `|f_est - f_gt|` over pixels valid in both and (when given) set in
/// `mask`, with the number of pixels counted. `None` when no pixel counts or sizes differ.
pub fn epe(estimate: &FlowField, truth: &FlowField, mask: Option<&Mask>) -> Option<(f64, usize)> {
    if estimate.flow.dims() != truth.flow.dims() || mask.is_some_and(|m| m.dims() != truth.flow.dims()) {
        return None;
    }
    let (mut sum, mut n) = (0.0f64, 0usize);
    for k in 0..truth.flow.as_slice().len() {
        if !estimate.valid.as_slice()[k] || !truth.valid.as_slice()[k] || mask.is_some_and(|m| !m.as_slice()[k]) {
            continue;
        }
        let (a, b) = (estimate.flow.as_slice()[k], truth.flow.as_slice()[k]);
        sum += f64::from(((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt());
        n += 1;
    }
    (n > 0).then(|| (sum / n as f64, n))
}

/// Mean end-point error of sparse estimates `(x, y, u, v)` against the truth at `(x, y)` (integer
/// pixels), skipping points where the truth is invalid.
pub fn epe_at_points(points: &[([usize; 2], Option<[f32; 2]>)], truth: &FlowField) -> Option<(f64, usize)> {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for &([x, y], est) in points {
        if let (Some(e), Some(t)) = (est, truth.at(x, y)) {
            sum += f64::from(((e[0] - t[0]).powi(2) + (e[1] - t[1]).powi(2)).sqrt());
            n += 1;
        }
    }
    (n > 0).then(|| (sum / n as f64, n))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn epe_of_a_constant_offset() {
        let truth = FlowField::zeros(10, 10);
        let mut est = FlowField::zeros(10, 10);
        est.flow.as_mut_slice().iter_mut().for_each(|f| *f = [3.0, 4.0]);
        assert_eq!(epe(&est, &truth, None), Some((5.0, 100)));
        let mask = Mask::from_fn(10, 10, |x, _| x < 5);
        assert_eq!(epe(&est, &truth, Some(&mask)).unwrap().1, 50);
        assert_eq!(epe_at_points(&[([1, 1], Some([0.0, 1.0])), ([2, 2], None)], &truth), Some((1.0, 1)));
        assert!(epe(&FlowField::zeros(3, 3), &truth, None).is_none());
    }
}
