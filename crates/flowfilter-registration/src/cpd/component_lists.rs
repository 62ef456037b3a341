//! Each observation's candidate components for the truncated E-step, gathered once around where
//! the observation was (in the components' unmoved frame) and reused while the iteration moves
//! it less than the lists' margin: near convergence the motion changes by micrometres per
//! iteration, and a fresh grid query per observation and iteration was most of the E-step's
//! time (the grid's cells hold about three times the points of the ball they stand for).

use flowfilter_geometry::{Point3, RadiusGrid};
use rayon::prelude::*;

/// Lists are gathered this much wider than the radius the E-step needs, so that they hold while
/// the observations move by the difference.
pub(super) const LIST_MARGIN: f64 = 1.2;

/// Lists wider than this many times the needed radius are gathered again (sigma has shrunk and
/// every extra candidate costs a distance per iteration).
const LIST_MAX_WIDTH: f64 = 1.5;

/// Lists are gathered again when more than this fraction of the observations has moved beyond
/// their margin (those fall back to the k-d tree until then).
const MAX_STALE_FRACTION: f64 = 0.05;

/// Candidate components per observation.
pub(super) struct ComponentLists {
    /// Gathering radius (unmoved units).
    radius: f64,
    /// Each observation's unmoved position when its list was gathered.
    at: Vec<Point3>,
    /// Per observation, the components within `radius` of `at` (the grid's order).
    lists: Vec<Box<[u32]>>,
}

impl ComponentLists {
    /// The components `y` within `radius` of each of `at`.
    pub(super) fn gather(y: &[Point3], at: Vec<Point3>, radius: f64) -> Option<Self> {
        let grid = RadiusGrid::new(y, radius)?;
        let lists = at
            .par_iter()
            .map_init(Vec::new, |found, q| {
                found.clear();
                grid.within(q, found);
                found.as_slice().into()
            })
            .collect();
        Some(Self { radius, at, lists })
    }

    /// Whether the lists still serve a pass that needs `need` around the observations now at
    /// `unmoved`: not too wide, and few observations moved beyond the margin.
    pub(super) fn serve(&self, unmoved: &[Point3], need: f64) -> bool {
        if unmoved.len() != self.at.len() || self.radius < need || self.radius > LIST_MAX_WIDTH * need {
            return false;
        }
        let margin2 = (self.radius - need).powi(2);
        let stale = unmoved.iter().zip(&self.at).filter(|(q, a)| (*q - *a).norm_squared() > margin2).count();
        (stale as f64) <= MAX_STALE_FRACTION * unmoved.len() as f64
    }

    /// Appends observation `n`'s log-kernel terms (see `ComponentSearch::terms`) from its list
    /// when the list certifies them: every component within `sqrt(d_near^2 + radius^2)` (moved
    /// units) of `q` must lie within the list's radius less the distance `q` has moved since.
    /// False (nothing appended) otherwise.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn terms(
        &self,
        n: usize,
        q: &Point3,
        y: &[Point3],
        s2: f64,
        radius: f64,
        inv: f64,
        terms: &mut Vec<(u32, f64)>,
    ) -> bool {
        let slack = self.radius - (q - self.at[n]).norm();
        if slack <= 0.0 {
            return false;
        }
        let start = terms.len();
        let mut near = f64::INFINITY;
        for &k in self.lists[n].iter() {
            let d2 = (y[k as usize] - q).norm_squared();
            near = near.min(d2);
            terms.push((k, d2));
        }
        let reach2 = near * s2 + radius * radius;
        if !(near.is_finite() && reach2 <= slack * slack * s2) {
            terms.truncate(start);
            return false;
        }
        let kept = reach2 / s2;
        let mut w = start;
        for i in start..terms.len() {
            let (k, d2) = terms[i];
            terms[w] = (k, d2 * s2 * inv);
            w += usize::from(d2 <= kept);
        }
        terms.truncate(w);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points(n: usize, seed: u64) -> Vec<Point3> {
        crate::test_clouds::uniform_box(n, seed, (0.2, 0.2, 0.01))
    }

    /// Terms from a list, when it certifies them, are the brute-force terms: every component
    /// within `sqrt(d_near^2 + radius^2)` of the observation; a move beyond the margin is refused.
    #[test]
    fn certified_terms_are_the_brute_force_terms() {
        let (y, at) = (points(3000, 1), points(400, 2));
        let (radius, inv, s2) = (0.01, -0.5 / 1e-5, 1.0);
        let lists = ComponentLists::gather(&y, at.clone(), LIST_MARGIN * 1.2 * radius).unwrap();
        let shift = nalgebra::Vector3::new(0.0012, -0.0007, 0.0003);
        let moved: Vec<Point3> = at.iter().map(|p| p + shift).collect();
        assert!(lists.serve(&moved, 1.2 * radius));
        let mut certified = 0;
        for (n, q) in moved.iter().enumerate() {
            let mut got = vec![];
            if !lists.terms(n, q, &y, s2, radius, inv, &mut got) {
                continue;
            }
            certified += 1;
            let near = y.iter().map(|c| (c - q).norm_squared()).fold(f64::INFINITY, f64::min);
            let reach2 = near + radius * radius;
            let mut want: Vec<(u32, f64)> = y
                .iter()
                .enumerate()
                .filter(|(_, c)| (*c - q).norm_squared() <= reach2)
                .map(|(k, c)| (k as u32, (c - q).norm_squared() * inv))
                .collect();
            got.sort_by_key(|t| t.0);
            want.sort_by_key(|t| t.0);
            assert_eq!(got, want, "observation {n}");
        }
        assert!(certified > 350, "{certified} of 400 certified");
        // Moved beyond the lists' radius: nothing is certified, and the lists no longer serve.
        let far: Vec<Point3> = at.iter().map(|p| p + nalgebra::Vector3::new(0.02, 0.0, 0.0)).collect();
        assert!(!lists.serve(&far, 1.2 * radius));
        assert!((0..far.len()).all(|n| !lists.terms(n, &far[n], &y, s2, radius, inv, &mut vec![])));
    }
}
