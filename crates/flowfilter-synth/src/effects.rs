//! What real RGB-D frames have and renders lack, beyond sensor noise: exposure and white-balance
//! changes between frames, object masks a few pixels off, and depth captured a moment before or
//! after colour. [`FrameEffects`] draws them per frame from a seeded generator.

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
}

impl FrameEffects {
    /// No effect: colour, masks and depth exactly as rendered.
    pub const NONE: Self =
        Self { exposure: 0.0, white_balance: 0.0, mask_shift_px: 0, mask_grow_px: 0, depth_delay_deg: 0.0 };

    /// What a handheld consumer RGB-D camera shows between two frames of a sequence: auto
    /// exposure within +-12%, white balance within +-4% per channel, masks (from a detector or
    /// from a pose annotation on a slightly misregistered image) up to 2 px off and up to 2 px
    /// too large or too small, and depth taken up to 0.1 degrees of rotation away from colour
    /// (about 10 ms at 10 deg/s).
    pub const REAL_SENSOR: Self =
        Self { exposure: 0.12, white_balance: 0.04, mask_shift_px: 2, mask_grow_px: 2, depth_delay_deg: 0.1 };

    /// Draw one frame's values.
    pub fn draw(&self, rng: &mut impl Rng) -> FrameDraw {
        let mut symmetric = |bound: f64| if bound > 0.0 { rng.random_range(-bound..=bound) } else { 0.0 };
        let exposure = 1.0 + symmetric(self.exposure);
        let gain = [0; 3].map(|_| exposure * (1.0 + symmetric(self.white_balance)));
        let depth_delay_deg = symmetric(self.depth_delay_deg);
        let mut whole = |bound: u32| {
            let b = bound as i32;
            if b > 0 { rng.random_range(-b..=b) } else { 0 }
        };
        let mask_shift = (whole(self.mask_shift_px), whole(self.mask_shift_px));
        let mask_grow = whole(self.mask_grow_px);
        FrameDraw { gain, mask_shift, mask_grow, depth_delay_deg }
    }
}

impl FrameDraw {
    /// Scale the colour channels by the drawn gains (saturating at 255).
    pub fn apply_gain(&self, img: &mut RgbImage) {
        for px in img.pixels_mut() {
            for (c, g) in px.0.iter_mut().zip(self.gain) {
                *c = (f64::from(*c) * g).round().clamp(0.0, 255.0) as u8;
            }
        }
    }

    /// The mask shifted, then grown or shrunk (a square neighbourhood).
    pub fn perturb_mask(&self, mask: &Mask) -> Mask {
        let (w, h) = mask.dims();
        let (dx, dy) = self.mask_shift;
        let at = |x: i64, y: i64| {
            x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h && *mask.at(x as usize, y as usize)
        };
        let shifted = Mask::from_fn(w, h, |x, y| at(x as i64 - i64::from(dx), y as i64 - i64::from(dy)));
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
            assert!(d.depth_delay_deg.abs() <= 0.1);
        }
        let d = FrameEffects::NONE.draw(&mut rng);
        assert_eq!(d, FrameDraw { gain: [1.0; 3], mask_shift: (0, 0), mask_grow: 0, depth_delay_deg: 0.0 });
        let m = square(20, 5, 15);
        assert_eq!(d.perturb_mask(&m), m);
    }

    #[test]
    fn masks_shift_grow_and_shrink() {
        let m = square(20, 5, 15);
        let shift = FrameDraw { gain: [1.0; 3], mask_shift: (2, -1), mask_grow: 0, depth_delay_deg: 0.0 };
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
        FrameDraw { gain: [1.1, 0.5, 1.1], mask_shift: (0, 0), mask_grow: 0, depth_delay_deg: 0.0 }
            .apply_gain(&mut img);
        assert_eq!(img.get_pixel(1, 0).0, [110, 100, 255]);
    }
}
