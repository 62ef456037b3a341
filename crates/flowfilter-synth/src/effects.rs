//! What real RGB-D frames have and renders lack, beyond sensor noise: exposure and white-balance
//! changes between frames, object masks a few pixels off, depth captured a moment before or
//! after colour, and a rolling shutter's row shear. [`FrameEffects`] draws them per frame from a
//! seeded generator.

use flowfilter_geometry::Mask;
use image::RgbImage;
use rand::Rng;

/// How strong each effect is; every frame draws its own values uniformly within these bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameEffects {
    /// Exposure change: every channel of a frame is scaled by one gain in `[1 - e, 1 + e]`.
    pub exposure: f64,
    /// White-balance change: each channel is scaled by its own further gain in `[1 - w, 1 + w]`.
    pub white_balance: f64,
    /// The object mask is shifted by up to this many pixels along each image axis.
    pub mask_shift_px: u32,
    /// The object mask is then grown or shrunk by up to this many pixels.
    pub mask_grow_px: u32,
    /// The depth image is taken with the object up to this many degrees of turntable rotation
    /// away from where it was for the colour image (either way).
    pub depth_delay_deg: f64,
    /// The colour image's rows are shifted sideways in proportion to their distance from the
    /// middle row, by up to this many pixels per row (either way): a rolling shutter exposes row
    /// after row, and when the image motion changes speed between two frames their rows shift
    /// against each other.
    pub row_shear_px_per_row: f64,
    /// The colour image's rows are also moved down (away from the middle row) in proportion to
    /// their distance from it, by up to this many pixels per row (either way): the same shutter
    /// when the image motion has a vertical part that changes speed (a stretch or squeeze of
    /// the rows).
    pub row_stretch_px_per_row: f64,
}

/// The values one frame drew.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameDraw {
    /// Per-channel colour gain (exposure times white balance).
    pub gain: [f64; 3],
    /// Mask shift, pixels (x, y).
    pub mask_shift: (i32, i32),
    /// Mask growth, pixels (negative: shrunk).
    pub mask_grow: i32,
    /// Turntable angle of the depth exposure minus that of the colour exposure, degrees.
    pub depth_delay_deg: f64,
    /// Sideways shift of the colour image's rows per row from the middle one, pixels.
    pub row_shear_px_per_row: f64,
    /// Downward shift of the colour image's rows per row from the middle one, pixels.
    pub row_stretch_px_per_row: f64,
}

impl FrameEffects {
    /// No effect: colour, masks and depth exactly as rendered.
    pub const NONE: Self = Self {
        exposure: 0.0,
        white_balance: 0.0,
        mask_shift_px: 0,
        mask_grow_px: 0,
        depth_delay_deg: 0.0,
        row_shear_px_per_row: 0.0,
        row_stretch_px_per_row: 0.0,
    };

    /// What a handheld consumer RGB-D camera shows between two frames of a sequence: auto
    /// exposure within +-12%, white balance within +-4% per channel, masks (from a detector or
    /// from a pose annotation on a slightly misregistered image) up to 2 px off and up to 2 px
    /// too large or too small, and depth taken up to 0.1 degrees of rotation away from colour
    /// (about 10 ms at 10 deg/s), and rows shifted by up to 0.004 px per row (two frames' rows
    /// then differ by up to 0.008 px per row: the real YCB-Video sample's frame pairs show
    /// 0.003-0.009).
    pub const REAL_SENSOR: Self = Self {
        exposure: 0.12,
        white_balance: 0.04,
        mask_shift_px: 2,
        mask_grow_px: 2,
        depth_delay_deg: 0.1,
        row_shear_px_per_row: 0.004,
        row_stretch_px_per_row: 0.0,
    };

    /// What the real YCB-Video sample (`../shared/data/ycb-video/0001`, Xtion) shows, measured
    /// against its synthetic twin (`cargo xtask twin`): its label masks are offset from the exact
    /// silhouettes by the same 2-3 px in every frame (within 0.1-0.7 px from frame to frame,
    /// areas within 2%), so a frame draws no mask shift or growth of its own (the common offset
    /// is [`crate::TwinOptions::mask_offset_px`]). Its rows shear and stretch: the direct image
    /// alignment's row shear on the 40 object pairs (`align_row_shear_x` / `_y` of `pairs.csv`)
    /// fitted as one shear per frame, frame minus frame, gives frames within +-0.0044 px per row
    /// sideways and +-0.0048 down (residuals 0.002 and 0.0015 RMS). Exposure and white balance as
    /// [`Self::REAL_SENSOR`]'s (not measured).
    pub const XTION_SAMPLE: Self = Self {
        mask_shift_px: 0,
        mask_grow_px: 0,
        row_shear_px_per_row: 0.0045,
        row_stretch_px_per_row: 0.005,
        ..Self::REAL_SENSOR
    };

    /// What the real RealSense SR300 shelf sequences (`../shared/data/realsense-shelf`) show
    /// between frames, for their twins: the arm stops at each pose, so no depth delay and no
    /// rolling-shutter shear; masks get the segmentation network's defects elsewhere
    /// (`NetworkMaskModel::SHELF_NETWORK`), so none here; the auto exposure's gain between two
    /// frames of a pair, measured against the twins (docs/real.md, "The synthetic twin").
    pub const SR300_SHELF: Self = Self {
        exposure: 0.12,
        white_balance: 0.04,
        mask_shift_px: 0,
        mask_grow_px: 0,
        depth_delay_deg: 0.0,
        row_shear_px_per_row: 0.0,
        row_stretch_px_per_row: 0.0,
    };

    /// Draw one frame's values.
    pub fn draw(&self, rng: &mut impl Rng) -> FrameDraw {
        let mut symmetric = |bound: f64| if bound > 0.0 { rng.random_range(-bound..=bound) } else { 0.0 };
        let exposure = 1.0 + symmetric(self.exposure);
        let gain = [0; 3].map(|_| exposure * (1.0 + symmetric(self.white_balance)));
        let depth_delay_deg = symmetric(self.depth_delay_deg);
        let row_shear_px_per_row = symmetric(self.row_shear_px_per_row);
        let row_stretch_px_per_row = symmetric(self.row_stretch_px_per_row);
        let mut whole = |bound: u32| {
            let b = bound as i32;
            if b > 0 { rng.random_range(-b..=b) } else { 0 }
        };
        let mask_shift = (whole(self.mask_shift_px), whole(self.mask_shift_px));
        let mask_grow = whole(self.mask_grow_px);
        FrameDraw { gain, mask_shift, mask_grow, depth_delay_deg, row_shear_px_per_row, row_stretch_px_per_row }
    }
}

impl FrameDraw {
    /// A draw that changes nothing (unit gains, masks as they are, no delay, shear or stretch):
    /// the start of a hand-made draw, `FrameDraw { row_shear_px_per_row: 0.008, ..FrameDraw::NONE }`.
    pub const NONE: Self = Self {
        gain: [1.0; 3],
        mask_shift: (0, 0),
        mask_grow: 0,
        depth_delay_deg: 0.0,
        row_shear_px_per_row: 0.0,
        row_stretch_px_per_row: 0.0,
    };

    /// Scale the colour channels by the drawn gains (saturating at 255).
    pub fn apply_gain(&self, img: &mut RgbImage) {
        for px in img.pixels_mut() {
            for (c, g) in px.0.iter_mut().zip(self.gain) {
                *c = (f64::from(*c) * g).round().clamp(0.0, 255.0) as u8;
            }
        }
    }

    /// Shift each row of `img` sideways by the drawn shear times its distance from the middle
    /// row, then down by the drawn stretch times that distance (linear interpolation; the edge
    /// pixels extend past the borders).
    pub fn apply_row_shear(&self, img: &mut RgbImage) {
        self.shift_rows_sideways(img);
        self.stretch_rows(img);
    }

    /// Each row sideways by the shear times its distance from the middle row.
    fn shift_rows_sideways(&self, img: &mut RgbImage) {
        let s = self.row_shear_px_per_row;
        if s == 0.0 || img.width() == 0 {
            return;
        }
        let (w, h) = (img.width(), img.height());
        let middle = (f64::from(h) - 1.0) / 2.0;
        for y in 0..h {
            let shift = s * (f64::from(y) - middle);
            let row: Vec<[u8; 3]> = (0..w).map(|x| img.get_pixel(x, y).0).collect();
            for x in 0..w {
                let (i, j, t) = linear_tap(f64::from(x) - shift, w);
                img.put_pixel(x, y, image::Rgb(blend(row[i as usize], row[j as usize], t)));
            }
        }
    }

    /// Each row down by the stretch times its distance from the middle row (the rows between
    /// blended).
    fn stretch_rows(&self, img: &mut RgbImage) {
        let s = self.row_stretch_px_per_row;
        if s == 0.0 || img.height() == 0 {
            return;
        }
        let (w, h) = (img.width(), img.height());
        let middle = (f64::from(h) - 1.0) / 2.0;
        let source = img.clone();
        for y in 0..h {
            let (i, j, t) = linear_tap(f64::from(y) - s * (f64::from(y) - middle), h);
            for x in 0..w {
                img.put_pixel(x, y, image::Rgb(blend(source.get_pixel(x, i).0, source.get_pixel(x, j).0, t)));
            }
        }
    }

    /// The mask shifted, then grown or shrunk (a square neighbourhood).
    pub fn perturb_mask(&self, mask: &Mask) -> Mask {
        let (w, h) = mask.dims();
        let (dx, dy) = self.mask_shift;
        let shifted = crate::network_mask::shifted(mask, (i64::from(dx), i64::from(dy)));
        let r = i64::from(self.mask_grow.unsigned_abs());
        if r == 0 {
            return shifted;
        }
        let grow = self.mask_grow > 0;
        let s = |x: i64, y: i64| {
            x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h && *shifted.at(x as usize, y as usize)
        };
        Mask::from_fn(w, h, |x, y| {
            let (x, y) = (x as i64, y as i64);
            let mut window = (-r..=r).flat_map(|oy| (-r..=r).map(move |ox| (x + ox, y + oy)));
            if grow { window.any(|(u, v)| s(u, v)) } else { window.all(|(u, v)| s(u, v)) }
        })
    }
}

/// The two neighbours `(i, i + 1)` (the last repeated at the end) of position `from` clamped to
/// `[0, len - 1]`, and the weight of the second: a linear interpolation along one axis.
fn linear_tap(from: f64, len: u32) -> (u32, u32, f64) {
    let from = from.clamp(0.0, f64::from(len - 1));
    let i = from.floor() as u32;
    (i, (i + 1).min(len - 1), from.fract())
}

/// `a` and `b` mixed with weight `t` on `b`, per channel, rounded.
fn blend(a: [u8; 3], b: [u8; 3], t: f64) -> [u8; 3] {
    [0, 1, 2].map(|c| (f64::from(a[c]) * (1.0 - t) + f64::from(b[c]) * t).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn square(w: usize, lo: usize, hi: usize) -> Mask {
        Mask::from_fn(w, w, |x, y| (lo..hi).contains(&x) && (lo..hi).contains(&y))
    }

    fn count(m: &Mask) -> usize {
        m.as_slice().iter().filter(|v| **v).count()
    }

    #[test]
    fn draws_stay_within_their_bounds_and_none_changes_nothing() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..200 {
            let d = FrameEffects::REAL_SENSOR.draw(&mut rng);
            assert!(d.gain.iter().all(|g| (0.88 * 0.96 - 1e-12..=1.12 * 1.04 + 1e-12).contains(g)), "{d:?}");
            assert!(d.mask_shift.0.abs() <= 2 && d.mask_shift.1.abs() <= 2 && d.mask_grow.abs() <= 2);
            assert!(d.depth_delay_deg.abs() <= 0.1 && d.row_shear_px_per_row.abs() <= 0.004);
        }
        let d = FrameEffects::NONE.draw(&mut rng);
        assert_eq!(d, FrameDraw { gain: [1.0; 3], ..STILL });
        let m = square(20, 5, 15);
        assert_eq!(d.perturb_mask(&m), m);
    }

    /// A draw that changes nothing.
    const STILL: FrameDraw = FrameDraw::NONE;

    #[test]
    fn masks_shift_grow_and_shrink() {
        let m = square(20, 5, 15);
        let shift = FrameDraw { mask_shift: (2, -1), ..STILL };
        let s = shift.perturb_mask(&m);
        assert!(*s.at(7, 4) && !*s.at(6, 14) && *s.at(16, 13) && !*s.at(17, 13));
        assert_eq!(count(&s), 100);
        let grown = FrameDraw { mask_shift: (0, 0), mask_grow: 1, ..shift }.perturb_mask(&m);
        assert_eq!(count(&grown), 144);
        let shrunk = FrameDraw { mask_shift: (0, 0), mask_grow: -2, ..shift }.perturb_mask(&m);
        assert_eq!(count(&shrunk), 36);
    }

    #[test]
    fn gains_scale_and_saturate() {
        let mut img = RgbImage::from_pixel(2, 1, image::Rgb([100, 200, 250]));
        FrameDraw { gain: [1.1, 0.5, 1.1], ..STILL }.apply_gain(&mut img);
        assert_eq!(img.get_pixel(1, 0).0, [110, 100, 255]);
    }

    /// A vertical edge leans: the rows below the middle move right, those above left, by the
    /// shear times their distance from the middle row; the middle row stays.
    #[test]
    fn the_row_shear_leans_a_vertical_edge() {
        let (w, h) = (40u32, 101u32);
        let edge = |img: &RgbImage, y: u32| (0..w).find(|&x| img.get_pixel(x, y).0[0] > 127).unwrap();
        let mut img = RgbImage::from_fn(w, h, |x, _| image::Rgb(if x < 20 { [0; 3] } else { [255; 3] }));
        FrameDraw { row_shear_px_per_row: 0.1, ..STILL }.apply_row_shear(&mut img);
        assert_eq!(edge(&img, 50), 20);
        assert_eq!(edge(&img, 100), 25);
        assert_eq!(edge(&img, 0), 15);
        // Half a pixel: the edge pixel blends.
        assert_eq!(img.get_pixel(20, 55).0[0], 128);
        let before = img.clone();
        STILL.apply_row_shear(&mut img);
        assert_eq!(img, before);
    }

    /// A horizontal edge moves away from the middle row by the stretch times its distance from
    /// it; the middle row stays.
    #[test]
    fn the_row_stretch_moves_a_horizontal_edge() {
        let (w, h) = (4u32, 101u32);
        let edge = |img: &RgbImage| (0..h).find(|&y| img.get_pixel(0, y).0[0] > 127).unwrap();
        let bar = |from: u32| RgbImage::from_fn(w, h, |_, y| image::Rgb(if y < from { [0; 3] } else { [255; 3] }));
        let mut below = bar(90);
        FrameDraw { row_stretch_px_per_row: 0.1, ..STILL }.apply_row_shear(&mut below);
        assert_eq!(edge(&below), 94); // 40 rows below the middle: 4 rows further down
        let mut middle = bar(50);
        FrameDraw { row_stretch_px_per_row: 0.1, ..STILL }.apply_row_shear(&mut middle);
        assert_eq!(edge(&middle), 50);
    }
}
