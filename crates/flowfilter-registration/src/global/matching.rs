//! Matches between two clouds' descriptors: mutual nearest neighbours in descriptor space (a
//! k-d tree over the 33 dimensions, kiddo's).

use super::fpfh::{FPFH_LEN, Fpfh};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

/// The pairs `(i, j)` where `target[j]` is the nearest descriptor to `source[i]` and
/// `source[i]` the nearest to `target[j]`, in source order. Empty when either side is.
///
/// # Examples
///
/// ```
/// use flowfilter_registration::global::{FPFH_LEN, mutual_matches};
///
/// let f = |v: f32| [v; FPFH_LEN];
/// // Source 0 and target 1 choose each other; source 1's nearest (target 1) prefers source 0.
/// assert_eq!(mutual_matches(&[f(1.0), f(1.4)], &[f(5.0), f(1.1)]), vec![(0, 1)]);
/// ```
pub fn mutual_matches(source: &[Fpfh], target: &[Fpfh]) -> Vec<(usize, usize)> {
    let (Some(forward), Some(backward)) = (nearest_of_each(source, target), nearest_of_each(target, source)) else {
        return vec![];
    };
    forward.iter().enumerate().filter(|&(i, &j)| backward[j] == i).map(|(i, &j)| (i, j)).collect()
}

/// For each of `queries`, the index of its nearest descriptor in `indexed`; `None` when either
/// is empty or a descriptor is not finite.
fn nearest_of_each(queries: &[Fpfh], indexed: &[Fpfh]) -> Option<Vec<usize>> {
    let finite = |d: &[Fpfh]| d.iter().all(|f| f.iter().all(|v| v.is_finite()));
    if queries.is_empty() || indexed.is_empty() || !finite(queries) || !finite(indexed) {
        return None;
    }
    let tree: ImmutableKdTree<f32, FPFH_LEN> = ImmutableKdTree::new_from_slice(indexed).ok()?;
    Some(
        queries
            .par_iter()
            .map(|q| tree.query(q).nearest_one::<SquaredEuclidean<f32>>().execute().item as usize)
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_mutual_nearest_pairs_are_kept() {
        let f = |v: f32, w: f32| {
            let mut d = [0.0; FPFH_LEN];
            (d[0], d[20]) = (v, w);
            d
        };
        let source = [f(0.0, 0.0), f(10.0, 0.0), f(10.5, 0.0), f(0.0, 10.0)];
        let target = [f(10.1, 0.0), f(0.1, 10.0), f(0.0, 0.2)];
        // Sources 1 and 2 both find target 0, which finds source 1: only (1, 0) is kept.
        assert_eq!(mutual_matches(&source, &target), vec![(0, 2), (1, 0), (3, 1)]);
        assert!(mutual_matches(&[], &target).is_empty());
        assert!(mutual_matches(&[f(f32::NAN, 0.0)], &target).is_empty());
    }
}
