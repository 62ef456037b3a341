//! Organised point clouds from depth maps, normals, voxel downsampling, outlier removal.

use flowfilter_camera::RayTable;
use flowfilter_geometry::fastmath;
use flowfilter_geometry::{DepthMap, KnnIndex, Mask, Point3, PointCloud, Vector3};
use image::RgbImage;
use nalgebra::Matrix3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;

/// An organised cloud: one point per pixel with depth (inside `mask` when given), in the
/// camera frame of `rays`, with pixel coordinates and (when `color` is given) colours. Also
/// returns, per pixel, the index of its point (`u32::MAX` for none).
pub fn organized_cloud(
    depth: &DepthMap,
    rays: &RayTable,
    color: Option<&RgbImage>,
    mask: Option<&Mask>,
) -> (PointCloud, Vec<u32>) {
    let region = match mask {
        Some(m) => crate::register::mask_bbox(m),
        None => Some((0, 0, depth.width() - 1, depth.height() - 1)),
    };
    organized_cloud_in(depth, rays, color, mask, region, 1)
}

/// [`organized_cloud`] over the pixels of `region` (inclusive box; `None` = no pixel), which
/// must hold every pixel of `mask`, taking the pixels whose coordinates are both multiples of
/// `step` (1: every pixel).
pub(crate) fn organized_cloud_in(
    depth: &DepthMap,
    rays: &RayTable,
    color: Option<&RgbImage>,
    mask: Option<&Mask>,
    region: Option<(usize, usize, usize, usize)>,
    step: usize,
) -> (PointCloud, Vec<u32>) {
    let w = depth.width();
    let n_pixels = depth.as_slice().len();
    let mut index: Vec<u32> = (0..n_pixels).into_par_iter().map(|_| u32::MAX).collect();
    let Some((x0, y0, x1, y1)) = region else {
        return (PointCloud { colors: color.map(|_| vec![]), pixels: Some(vec![]), ..Default::default() }, index);
    };
    // Pixels whose ray lies outside the camera model's domain have no point.
    let step = step.max(1);
    let keep = |x: usize, y: usize| {
        let k = y * w + x;
        x.is_multiple_of(step)
            && y.is_multiple_of(step)
            && depth.as_slice()[k] > 0.0
            && mask.is_none_or(|m| m.as_slice()[k])
            && rays.ray(x, y).is_some()
    };
    // Two passes over the box's rows, both parallel: count each row's points, then write them
    // at their row's offset (the same order as a sequential scan).
    let counts: Vec<usize> = (y0..=y1).into_par_iter().map(|y| (x0..=x1).filter(|&x| keep(x, y)).count()).collect();
    let n: usize = counts.iter().sum();
    let mut points = vec![Point3::origin(); n];
    let mut pixels = vec![[0.0f32; 2]; n];
    let mut colors = vec![[0u8; 3]; if color.is_some() { n } else { 0 }];
    // Per-row output slices.
    let mut rows = Vec::with_capacity(counts.len());
    let (mut pts, mut pxs, mut cols, mut first) = (&mut points[..], &mut pixels[..], &mut colors[..], 0usize);
    let mut index_rows = index[y0 * w..(y1 + 1) * w].chunks_mut(w);
    for (i, &c) in counts.iter().enumerate() {
        let (p, rest_p) = pts.split_at_mut(c);
        let (q, rest_q) = pxs.split_at_mut(c);
        let (k, rest_c) = cols.split_at_mut(if color.is_some() { c } else { 0 });
        rows.push((y0 + i, first, p, q, k, index_rows.next().expect("one index row per box row")));
        (pts, pxs, cols, first) = (rest_p, rest_q, rest_c, first + c);
    }
    rows.into_par_iter().for_each(|(y, first, p, q, k, index_row)| {
        for (i, x) in (x0..=x1).filter(|&x| keep(x, y)).enumerate() {
            let z = f64::from(depth.as_slice()[y * w + x]);
            p[i] = rays.backproject(x, y, z).expect("kept pixels have a ray");
            q[i] = [x as f32, y as f32];
            index_row[x] = (first + i) as u32;
            if let (Some(img), Some(c)) = (color, k.get_mut(i)) {
                *c = img.get_pixel(x as u32, y as u32).0;
            }
        }
    });
    let cloud = PointCloud { points, normals: None, colors: color.map(|_| colors), pixels: Some(pixels) };
    (cloud, index)
}

/// Orient `n` towards the camera centre (the origin) as seen from `p`.
fn towards_viewpoint(n: Vector3, p: &Point3) -> Vector3 {
    if n.dot(&p.coords) > 0.0 { -n } else { n }
}

/// Normals of an organised cloud from central differences `step` pixels apart on the grid
/// (`index` from [`organized_cloud`]); differences across more than `max_step_m` in depth are
/// not used; points without two usable directions get the normal from the viewing ray.
pub fn organized_normals(
    cloud: &PointCloud,
    index: &[u32],
    width: usize,
    step: usize,
    max_step_m: f64,
) -> Vec<Vector3> {
    let pixels = cloud.pixels.as_ref().expect("organised cloud has pixels");
    let height = index.len() / width;
    let at = |x: isize, y: isize| -> Option<Point3> {
        if x < 0 || y < 0 || x >= width as isize || y >= height as isize {
            return None;
        }
        let i = index[y as usize * width + x as usize];
        (i != u32::MAX).then(|| cloud.points[i as usize])
    };
    cloud
        .points
        .par_iter()
        .zip(pixels.par_iter())
        .map(|(p, px)| {
            let (x, y, s) = (px[0] as isize, px[1] as isize, step as isize);
            let diff = |a: Option<Point3>, b: Option<Point3>| -> Option<Vector3> {
                let near = |q: &Point3| (q.z - p.z).abs() <= max_step_m;
                match (a.filter(near), b.filter(near)) {
                    (Some(a), Some(b)) => Some(b - a),
                    (Some(a), None) => Some(p - a),
                    (None, Some(b)) => Some(b - p),
                    (None, None) => None,
                }
            };
            let n = match (diff(at(x - s, y), at(x + s, y)), diff(at(x, y - s), at(x, y + s))) {
                (Some(du), Some(dv)) => du.cross(&dv).try_normalize(1e-12),
                _ => None,
            };
            towards_viewpoint(n.unwrap_or_else(|| -p.coords.normalize()), p)
        })
        .collect()
}

/// Normals by PCA over the `k` nearest neighbours (smallest-eigenvalue eigenvector of the
/// neighbourhood covariance), oriented towards `viewpoint`, as Open3D's `estimate_normals`
/// with `KDTreeSearchParamKNN` and `orient_normals_towards_camera_location`.
pub fn knn_normals(points: &[Point3], k: usize, viewpoint: &Point3) -> Vec<Vector3> {
    let index = KnnIndex::new(points);
    points
        .par_iter()
        .map(|p| {
            let nb = index.k_nearest(p, k);
            let mean = nb.iter().fold(Vector3::zeros(), |a, n| a + points[n.index].coords) / nb.len().max(1) as f64;
            let cov = nb.iter().fold(Matrix3::zeros(), |a, n| {
                let d = points[n.index].coords - mean;
                a + d * d.transpose()
            });
            let eig = cov.symmetric_eigen();
            let i = eig.eigenvalues.imin();
            let n: Vector3 = eig.eigenvectors.column(i).into_owned();
            let n = n.try_normalize(1e-12).unwrap_or_else(Vector3::z);
            if n.dot(&(viewpoint - p)) < 0.0 { -n } else { n }
        })
        .collect()
}

/// Voxel-grid downsampling: one point per occupied voxel of edge `voxel` metres, the mean of
/// its points (colours and normals averaged too; normals renormalised). Voxels are emitted in
/// lexicographic order of their integer coordinates, so the result is deterministic.
pub fn voxel_downsample(cloud: &PointCloud, voxel: f64) -> PointCloud {
    let cells = voxel_sums(cloud, voxel);
    let mut out = PointCloud {
        points: Vec::with_capacity(cells.len()),
        normals: cloud.normals.as_ref().map(|_| Vec::with_capacity(cells.len())),
        colors: cloud.colors.as_ref().map(|_| Vec::with_capacity(cells.len())),
        ..Default::default()
    };
    for cell in cells {
        let n = cell.count as f64;
        out.points.push(Point3::from(cell.sum / n));
        if let Some(v) = &mut out.normals {
            v.push(cell.normal_sum.try_normalize(1e-12).unwrap_or_else(Vector3::z));
        }
        if let Some(v) = &mut out.colors {
            v.push(cell.color_sum.map(|c| (c / n).round() as u8));
        }
    }
    out
}

/// One occupied voxel's sums.
struct VoxelSums {
    key: [i64; 3],
    count: usize,
    sum: Vector3,
    normal_sum: Vector3,
    color_sum: [f64; 3],
}

/// The sums of every occupied voxel, in lexicographic order of the voxels' integer
/// coordinates; each voxel's points added in index order. The points are visited in index
/// order, and a point in the voxel of the point before it (most of them: a scan of an image's
/// pixels stays in one voxel for several) skips the voxel look-up (a whole 640 x 480 frame's
/// 142k points at 4 mm: 6.1 -> 3.9 ms on one thread against a radix sort of all their keys).
fn voxel_sums(cloud: &PointCloud, voxel: f64) -> Vec<VoxelSums> {
    let mut cells: Vec<VoxelSums> = Vec::new();
    scan_voxels(cloud, voxel, |i, slot, new| {
        if let Some(key) = new {
            cells.push(VoxelSums {
                key,
                count: 0,
                sum: Vector3::zeros(),
                normal_sum: Vector3::zeros(),
                color_sum: [0.0; 3],
            });
        }
        let cell = &mut cells[slot];
        cell.count += 1;
        cell.sum += cloud.points[i].coords;
        if let Some(n) = &cloud.normals {
            cell.normal_sum += n[i];
        }
        if let Some(c) = &cloud.colors {
            for (acc, v) in cell.color_sum.iter_mut().zip(c[i]) {
                *acc += f64::from(v);
            }
        }
    });
    cells.sort_unstable_by_key(|c| c.key);
    cells
}

/// Every point of `cloud` in index order with the slot of its voxel of edge `voxel` (slots
/// numbered in the order their voxels are first met) and, where the voxel is new, its key:
/// `each(point, slot, new_key)`. A point in the voxel of the point before it skips the look-up.
/// Returns the number of occupied voxels.
fn scan_voxels(cloud: &PointCloud, voxel: f64, mut each: impl FnMut(usize, usize, Option<[i64; 3]>)) -> usize {
    let mut slot_of: FxHashMap<[i64; 3], usize> = FxHashMap::default();
    let mut last: Option<([i64; 3], usize)> = None;
    for (i, p) in cloud.points.iter().enumerate() {
        let key = voxel_key(p, voxel);
        let (slot, new) = match last {
            Some((k, slot)) if k == key => (slot, None),
            _ => {
                let fresh = slot_of.len();
                let slot = *slot_of.entry(key).or_insert(fresh);
                (slot, (slot == fresh).then_some(key))
            }
        };
        last = Some((key, slot));
        each(i, slot, new);
    }
    slot_of.len()
}

/// The integer coordinates of the voxel of edge `voxel` that holds `p`.
fn voxel_key(p: &Point3, voxel: f64) -> [i64; 3] {
    let key_of = |x: f64| {
        let q = x / voxel;
        // `q.floor() as i64` (the fast form where it cannot overflow).
        if q.abs() < 4.0e18 { fastmath::floor_i64(q) } else { q.floor() as i64 }
    };
    [key_of(p.x), key_of(p.y), key_of(p.z)]
}

/// How many points [`voxel_downsample`] gives: the occupied voxels, counted without their sums.
fn voxel_count(cloud: &PointCloud, voxel: f64) -> usize {
    scan_voxels(cloud, voxel, |_, _, _| {})
}

/// `cloud`, already thinned with [`voxel_downsample`] at `voxel` metres (0: not thinned),
/// thinned again with a grown voxel until at most `max_points` remain (0: no limit): a
/// registration cloud bounded by a budget, whatever the object's size (a whole frame, an object
/// close to the camera). Returns the cloud and its voxel (`voxel` when the budget did not bind).
/// The voxel starts a little below where a surface's count would fit (the count falls with the
/// voxel's area) and is approached from below in steps of [`BUDGET_STEP`], so the cloud keeps
/// close to `max_points` (within one step's thinning, about a tenth on a surface): a rule that
/// reads the count (a scene's) still sees a large cloud. The result is deterministic.
///
/// ```
/// use flowfilter_depth::cloud::{thin_to_budget, voxel_downsample};
/// use flowfilter_geometry::{Point3, PointCloud};
///
/// // A 40 x 40 cm plane sampled every millimetre: 160 000 points, 10 000 at 4 mm.
/// let points = (0..400).flat_map(|i| (0..400).map(move |j| Point3::new(i as f64 * 1e-3, j as f64 * 1e-3, 1.0)));
/// let at_4mm = voxel_downsample(&PointCloud::from_points(points.collect()), 0.004);
/// assert_eq!(thin_to_budget(at_4mm.clone(), 0.004, 0).0.len(), 10_000);
/// let (bounded, voxel) = thin_to_budget(at_4mm, 0.004, 4000);
/// assert!(bounded.len() <= 4000 && bounded.len() > 3000, "{}", bounded.len());
/// assert!(voxel > 0.006 && voxel < 0.008, "{voxel}");
/// ```
pub fn thin_to_budget(cloud: PointCloud, voxel: f64, max_points: usize) -> (PointCloud, f64) {
    if max_points == 0 || cloud.len() <= max_points {
        return (cloud, voxel);
    }
    let start = if voxel > 0.0 { voxel } else { BUDGET_START_VOXEL_M };
    // Where a surface's count would fit, a little below; back down while that already fits.
    // The voxel is chosen on counts alone; the cloud is thinned once, with the voxel chosen.
    let mut grown = (start * 0.9 * (cloud.len() as f64 / max_points as f64).sqrt()).max(start);
    let mut count = voxel_count(&cloud, grown);
    while count <= max_points && grown / BUDGET_STEP > start {
        grown /= BUDGET_STEP;
        count = voxel_count(&cloud, grown);
    }
    while count > max_points {
        grown *= BUDGET_STEP;
        count = voxel_count(&cloud, grown);
    }
    (voxel_downsample(&cloud, grown), grown)
}

/// The factor by which [`thin_to_budget`] grows (or shrinks) its voxel at each step.
pub const BUDGET_STEP: f64 = 1.05;

/// The voxel [`thin_to_budget`] grows from when no voxel thinned the cloud first (metres).
const BUDGET_START_VOXEL_M: f64 = 0.001;

/// Statistical outlier removal (as Open3D's `remove_statistical_outlier`): drop points whose
/// mean distance to their `k` nearest neighbours exceeds the cloud-wide mean of that quantity by
/// more than `std_ratio` standard deviations. Returns the kept cloud and the kept indices.
pub fn remove_statistical_outliers(cloud: &PointCloud, k: usize, std_ratio: f64) -> (PointCloud, Vec<usize>) {
    if cloud.len() <= k {
        return (cloud.clone(), (0..cloud.len()).collect());
    }
    let index = KnnIndex::new(&cloud.points);
    let mean_d: Vec<f64> = cloud
        .points
        .par_iter()
        .map(|p| {
            let nb = index.k_nearest(p, k + 1); // the point itself comes first
            nb.iter().skip(1).map(|n| n.dist2.sqrt()).sum::<f64>() / k as f64
        })
        .collect();
    let n = mean_d.len() as f64;
    let mu = mean_d.iter().sum::<f64>() / n;
    let sd = (mean_d.iter().map(|d| (d - mu).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let keep: Vec<usize> = (0..cloud.len()).filter(|&i| mean_d[i] <= mu + std_ratio * sd).collect();
    (cloud.select(&keep), keep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn plane() -> Vec<Point3> {
        (0..400)
            .map(|i| Point3::new((i % 20) as f64 * 0.01, (i / 20) as f64 * 0.01, 1.0 + 0.5 * (i % 20) as f64 * 0.01))
            .collect()
    }

    /// The voxel grid as a map of voxels in key order would give it, point for point (each
    /// voxel's points added in the same order), with the points in a scrambled order and in scan
    /// order (runs of one voxel), and with coordinates far beyond any scene's.
    #[test]
    fn voxel_runs_equal_a_map_of_voxels() {
        let by_map = |cloud: &PointCloud, voxel: f64| {
            let mut cells: BTreeMap<[i64; 3], (Vector3, Vector3, usize)> = BTreeMap::new();
            for (i, p) in cloud.points.iter().enumerate() {
                let key = [(p.x / voxel).floor() as i64, (p.y / voxel).floor() as i64, (p.z / voxel).floor() as i64];
                let e = cells.entry(key).or_insert((Vector3::zeros(), Vector3::zeros(), 0));
                (e.0, e.1, e.2) = (e.0 + p.coords, e.1 + cloud.normals.as_ref().unwrap()[i], e.2 + 1);
            }
            let points: Vec<Point3> = cells.values().map(|(s, _, n)| Point3::from(s / *n as f64)).collect();
            let normals: Vec<Vector3> = cells.values().map(|(_, s, _)| s.try_normalize(1e-12).unwrap()).collect();
            (points, normals)
        };
        // A wavy sheet crossing zero on every axis, points in a scrambled order.
        let points: Vec<Point3> = (0..5000)
            .map(|k| {
                let i = k * 2477 % 5000;
                let (u, v) = ((i % 71) as f64 * 0.004 - 0.13, (i / 71) as f64 * 0.0035 - 0.1);
                Point3::new(u, v, 0.02 * (u * 40.0).sin() - 0.01)
            })
            .collect();
        let normals = points.iter().map(|p| Vector3::new(p.x, p.y, 1.0).normalize()).collect();
        let mut cloud = PointCloud { points, normals: Some(normals), ..Default::default() };
        for voxel in [0.003, 0.01] {
            let got = voxel_downsample(&cloud, voxel);
            assert_eq!(voxel_count(&cloud, voxel), got.len());
            assert_eq!((got.points, got.normals.unwrap()), by_map(&cloud, voxel));
        }
        let mut scan = cloud.clone();
        let order: Vec<usize> = (0..5000).map(|k| k * 2477 % 5000).collect();
        for (k, &i) in order.iter().enumerate() {
            scan.points[i] = cloud.points[k];
            scan.normals.as_mut().unwrap()[i] = cloud.normals.as_ref().unwrap()[k];
        }
        let got = voxel_downsample(&scan, 0.01);
        assert_eq!((got.points, got.normals.unwrap()), by_map(&scan, 0.01));
        cloud.points[0] = Point3::new(1e16, -1e16, 0.0);
        cloud.points[1] = Point3::new(-1e30, 1e30, 2.0);
        let got = voxel_downsample(&cloud, 0.003);
        assert_eq!((got.points, got.normals.unwrap()), by_map(&cloud, 0.003));
    }

    /// The row-parallel organised cloud equals a sequential scan: same points in row order, same
    /// pixels, colours and index.
    #[test]
    fn organized_cloud_matches_a_sequential_scan() {
        use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics};
        let cam = CameraModel::new(
            Intrinsics::new(120.0, 121.0, 39.5, 29.5).unwrap(),
            Distortion { k1: 0.05, k2: -0.02, p1: 0.001, p2: 0.0, k3: 0.0 },
            ImageSize::new(80, 60).unwrap(),
        );
        let rays = RayTable::new(&cam);
        let depth =
            DepthMap::from_fn(80, 60, |x, y| if (x * 7 + y * 3) % 5 == 0 { 0.0 } else { 0.5 + 0.001 * x as f32 });
        let mask = Mask::from_fn(80, 60, |x, y| (10..70).contains(&x) && (5..50).contains(&y) && (x + y) % 11 != 0);
        let color = RgbImage::from_fn(80, 60, |x, y| image::Rgb([x as u8, y as u8, (x + y) as u8]));
        let (cloud, index) = organized_cloud(&depth, &rays, Some(&color), Some(&mask));
        let mut want = Vec::new();
        for y in 0..60 {
            for x in 0..80 {
                let k = y * 80 + x;
                if depth.as_slice()[k] > 0.0
                    && mask.as_slice()[k]
                    && let Some(p) = rays.backproject(x, y, f64::from(depth.as_slice()[k]))
                {
                    want.push((k, p, [x as f32, y as f32], color.get_pixel(x as u32, y as u32).0));
                }
            }
        }
        assert!(want.len() > 1500);
        assert_eq!(cloud.len(), want.len());
        for (i, (k, p, px, c)) in want.iter().enumerate() {
            assert_eq!(
                (cloud.points[i], cloud.pixels.as_ref().unwrap()[i], cloud.colors.as_ref().unwrap()[i]),
                (*p, *px, *c)
            );
            assert_eq!(index[*k], i as u32);
        }
        assert_eq!(index.iter().filter(|&&v| v != u32::MAX).count(), want.len());
    }

    #[test]
    fn knn_normals_of_a_plane_face_the_camera() {
        let pts = plane();
        let expected = Vector3::new(0.5, 0.0, -1.0).normalize();
        for n in knn_normals(&pts, 10, &Point3::origin()) {
            assert!((n - expected).norm() < 1e-9, "{n:?}");
        }
    }

    /// `cloud` at `voxel` (0: every point), then within `max_points`: what the pipeline's
    /// cloud preparation does.
    fn voxel_downsample_within(cloud: &PointCloud, voxel: f64, max_points: usize) -> (PointCloud, f64) {
        let thinned = if voxel > 0.0 { voxel_downsample(cloud, voxel) } else { cloud.clone() };
        thin_to_budget(thinned, voxel, max_points)
    }

    #[test]
    fn a_budget_bounds_the_cloud_and_leaves_a_smaller_one_as_it_was() {
        let cloud = PointCloud::from_points(plane());
        let free = voxel_downsample(&cloud, 0.02);
        for budget in [0, 100, 1000] {
            let (kept, voxel) = voxel_downsample_within(&cloud, 0.02, budget);
            assert_eq!((kept.points, voxel), (free.points.clone(), 0.02), "budget {budget}");
        }
        for budget in [10, 37, 99] {
            let (bounded, voxel) = voxel_downsample_within(&cloud, 0.02, budget);
            assert!(bounded.len() <= budget && bounded.len() * 2 > budget, "{budget}: {}", bounded.len());
            assert!(voxel > 0.02, "{budget}: {voxel}");
            assert_eq!(bounded.points, voxel_downsample_within(&cloud, 0.02, budget).0.points, "deterministic");
        }
        // A large cloud keeps close to its budget: a 40 x 40 cm plane at 1 mm and a box's five
        // walls (a tote seen from above) both land within a step's thinning of 4000 points.
        let plane: Vec<Point3> =
            (0..400).flat_map(|i| (0..400).map(move |j| Point3::new(i as f64 * 1e-3, j as f64 * 1e-3, 1.0))).collect();
        let mut tote = plane.clone();
        for k in 0..300 {
            let z = 1.0 - k as f64 * 1e-3;
            for i in (0..400).step_by(2) {
                let t = i as f64 * 1e-3;
                tote.extend([
                    Point3::new(t, 0.0, z),
                    Point3::new(t, 0.399, z),
                    Point3::new(0.0, t, z),
                    Point3::new(0.399, t, z),
                ]);
            }
        }
        for points in [plane, tote] {
            let (kept, _) = voxel_downsample_within(&PointCloud::from_points(points), 0.004, 4000);
            assert!(kept.len() <= 4000 && kept.len() > 3400, "{}", kept.len());
        }
        // Without a first voxel every point is kept up to the budget.
        assert_eq!(voxel_downsample_within(&cloud, 0.0, 0).0.len(), cloud.len());
        assert!(voxel_downsample_within(&cloud, 0.0, 50).0.len() <= 50);
    }

    #[test]
    fn voxel_grid_averages_and_outliers_are_removed() {
        let mut cloud = PointCloud::from_points(plane());
        let down = voxel_downsample(&cloud, 0.02);
        assert_eq!(down.len(), 100);
        assert!((down.points[0] - Point3::new(0.005, 0.005, 1.0025)).norm() < 1e-12);
        cloud.points.push(Point3::new(0.1, 0.1, 3.0));
        let (kept, idx) = remove_statistical_outliers(&cloud, 8, 2.0);
        assert_eq!(kept.len(), 400);
        assert!(!idx.contains(&400));
    }
}
