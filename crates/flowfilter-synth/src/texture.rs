//! Procedural textures rich enough for optical flow: coloured stripes, rows of text-like
//! glyphs and value noise, as on packaged goods.

use image::{Rgb, RgbImage};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_colour(rng: &mut impl Rng) -> [f32; 3] {
    [rng.random_range(0.05..0.95), rng.random_range(0.05..0.95), rng.random_range(0.05..0.95)]
}

/// Smooth value noise in [-1, 1] on a `cells x cells` lattice, bilinearly interpolated.
struct ValueNoise {
    cells: usize,
    values: Vec<f32>,
}

impl ValueNoise {
    fn new(cells: usize, rng: &mut impl Rng) -> Self {
        Self { cells, values: (0..(cells + 1) * (cells + 1)).map(|_| rng.random_range(-1.0..1.0)).collect() }
    }

    fn at(&self, u: f32, v: f32) -> f32 {
        let (x, y) = (u * self.cells as f32, v * self.cells as f32);
        let (x0, y0) = ((x as usize).min(self.cells - 1), (y as usize).min(self.cells - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let g = |i: usize, j: usize| self.values[j * (self.cells + 1) + i];
        let top = g(x0, y0) * (1.0 - fx) + g(x0 + 1, y0) * fx;
        let bottom = g(x0, y0 + 1) * (1.0 - fx) + g(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// A label texture: background, horizontal colour bands, rows of 5x7 pseudo-glyphs of varied
/// size, a few large blocks, and two octaves of value noise. Deterministic in `seed`.
pub fn label(width: u32, height: u32, seed: u64) -> RgbImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut canvas: Vec<[f32; 3]> = vec![random_colour(&mut rng); (width * height) as usize];
    let put = |canvas: &mut Vec<[f32; 3]>, x: i64, y: i64, c: [f32; 3]| {
        if x >= 0 && y >= 0 && (x as u32) < width && (y as u32) < height {
            canvas[(y as u32 * width + x as u32) as usize] = c;
        }
    };
    // Colour bands.
    for _ in 0..rng.random_range(1..4) {
        let y0 = rng.random_range(0..height) as i64;
        let h = rng.random_range(height / 60..height / 16).max(1) as i64;
        let c = random_colour(&mut rng);
        for y in y0..y0 + h {
            for x in 0..width as i64 {
                put(&mut canvas, x, y, c);
            }
        }
    }
    // Large blocks (logos, panels).
    for _ in 0..rng.random_range(5..12) {
        let (bw, bh) =
            (rng.random_range(width / 10..width / 3) as i64, rng.random_range(height / 10..height / 4) as i64);
        let (x0, y0) = (rng.random_range(0..width) as i64, rng.random_range(0..height) as i64);
        let c = random_colour(&mut rng);
        let round = rng.random_bool(0.5);
        for y in y0..y0 + bh {
            for x in x0..x0 + bw {
                let (dx, dy) = ((x - x0) as f32 / bw as f32 - 0.5, (y - y0) as f32 / bh as f32 - 0.5);
                if !round || dx * dx + dy * dy < 0.25 {
                    put(&mut canvas, x, y, c);
                }
            }
        }
    }
    // Rows of glyphs ("text").
    let rows = rng.random_range(8..16);
    for _ in 0..rows {
        // Print of a few millimetres to a few centimetres: glyph cells of 1/64 to 1/24 of the
        // label height, with horizontal as well as vertical strokes for optical flow.
        let scale = rng.random_range((height / 64).max(2)..(height / 24).max(3)) as i64;
        let y0 = rng.random_range(0..height) as i64;
        let mut x = rng.random_range(0..width / 4) as i64;
        let end = x + rng.random_range(width / 4..width) as i64;
        let ink = if rng.random_bool(0.5) { [0.05, 0.05, 0.08] } else { random_colour(&mut rng) };
        while x < end {
            if rng.random_bool(0.15) {
                x += 4 * scale; // word gap
                continue;
            }
            let glyph: u64 = rng.random();
            for gy in 0..7 {
                for gx in 0..5 {
                    if glyph >> (gy * 5 + gx) & 1 == 1 {
                        for sy in 0..scale {
                            for sx in 0..scale {
                                put(&mut canvas, x + gx * scale + sx, y0 + gy * scale + sy, ink);
                            }
                        }
                    }
                }
            }
            x += 6 * scale;
        }
    }
    let coarse = ValueNoise::new(8, &mut rng);
    let fine = ValueNoise::new(64, &mut rng);
    RgbImage::from_fn(width, height, |x, y| {
        let (u, v) = (x as f32 / width as f32, y as f32 / height as f32);
        let n = 0.08 * coarse.at(u, v) + 0.05 * fine.at(u, v);
        let c = canvas[(y * width + x) as usize];
        Rgb(c.map(|ch| ((ch + n).clamp(0.0, 1.0) * 255.0).round() as u8))
    })
}

/// A plain surface: one colour with faint noise (the turntable disc, can lids).
pub fn plain(width: u32, height: u32, colour: [f32; 3], amplitude: f32, seed: u64) -> RgbImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = ValueNoise::new(32, &mut rng);
    RgbImage::from_fn(width, height, |x, y| {
        let n = amplitude * noise.at(x as f32 / width as f32, y as f32 / height as f32);
        Rgb(colour.map(|ch| ((ch + n).clamp(0.0, 1.0) * 255.0).round() as u8))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn label_is_deterministic_and_textured() {
        let a = label(256, 128, 7);
        assert_eq!(a, label(256, 128, 7));
        assert_ne!(a, label(256, 128, 8));
        // Rich texture: strong horizontal gradients in many places.
        let strong = (0..128)
            .flat_map(|y| (1..256).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let (p, q) = (a.get_pixel(x, y).0, a.get_pixel(x - 1, y).0);
                (0..3).map(|k| p[k].abs_diff(q[k]) as u32).sum::<u32>() > 60
            })
            .count();
        assert!(strong > 256 * 128 / 50, "only {strong} strong edges");
    }
}
