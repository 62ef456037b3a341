//! Flow visualisation with the Middlebury colour wheel (Baker et al., IJCV 2011): hue encodes
//! direction, saturation encodes magnitude relative to the largest flow shown.

use crate::FlowField;
use image::{Rgb, RgbImage};

/// The 55 colours of the wheel: red-yellow 15, yellow-green 6, green-cyan 4, cyan-blue 11,
/// blue-magenta 13, magenta-red 6.
fn wheel() -> Vec<[f32; 3]> {
    let mut w = Vec::with_capacity(55);
    let ramp = |n: usize, f: &dyn Fn(f32) -> [f32; 3], w: &mut Vec<[f32; 3]>| {
        for i in 0..n {
            w.push(f(i as f32 / n as f32));
        }
    };
    ramp(15, &|t| [1.0, t, 0.0], &mut w);
    ramp(6, &|t| [1.0 - t, 1.0, 0.0], &mut w);
    ramp(4, &|t| [0.0, 1.0, t], &mut w);
    ramp(11, &|t| [0.0, 1.0 - t, 1.0], &mut w);
    ramp(13, &|t| [t, 0.0, 1.0], &mut w);
    ramp(6, &|t| [1.0, 0.0, 1.0 - t], &mut w);
    w
}

/// Colour-code a flow field; invalid pixels are black. `max_magnitude` = `None` normalises by
/// the largest valid magnitude.
pub fn colorize(field: &FlowField, max_magnitude: Option<f32>) -> RgbImage {
    let wheel = wheel();
    let n = wheel.len() as f32;
    let max = max_magnitude.unwrap_or_else(|| {
        field
            .flow
            .as_slice()
            .iter()
            .zip(field.valid.as_slice())
            .filter(|(_, v)| **v)
            .map(|(f, _)| (f[0] * f[0] + f[1] * f[1]).sqrt())
            .fold(0.0, f32::max)
    });
    RgbImage::from_fn(field.width() as u32, field.height() as u32, |x, y| {
        let Some([u, v]) = field.at(x as usize, y as usize) else { return Rgb([0, 0, 0]) };
        let rad = ((u * u + v * v).sqrt() / max.max(1e-9)).min(1.0);
        let a = (-v).atan2(-u) / std::f32::consts::PI; // -1..1
        let fk = (a + 1.0) / 2.0 * (n - 1.0);
        let (k0, f) = (fk.floor() as usize, fk - fk.floor());
        let k1 = (k0 + 1) % wheel.len();
        Rgb(std::array::from_fn(|c| {
            let col = (1.0 - f) * wheel[k0][c] + f * wheel[k1][c];
            ((1.0 - rad * (1.0 - col)) * 255.0).round() as u8
        }))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_flow_is_white_and_directions_differ() {
        let mut f = FlowField::zeros(3, 1);
        f.flow.as_mut_slice()[1] = [5.0, 0.0];
        f.flow.as_mut_slice()[2] = [0.0, 5.0];
        let img = colorize(&f, None);
        assert_eq!(img.get_pixel(0, 0).0, [255, 255, 255]);
        assert_ne!(img.get_pixel(1, 0), img.get_pixel(2, 0));
        f.valid.as_mut_slice()[0] = false;
        assert_eq!(colorize(&f, None).get_pixel(0, 0).0, [0, 0, 0]);
    }
}
