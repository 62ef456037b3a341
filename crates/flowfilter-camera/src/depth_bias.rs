//! [`DepthBias`]: a depth sensor's own error, a smooth field over its image that its readings
//! are off by wherever the scene is (the structured-light "wave" of an SR300 or a Kinect v1).
//!
//! The field is a grid of control values, cell centres spread evenly over the depth image and
//! read bilinearly between them (clamped at the border). A reading `z` at pixel `(u, v)` is
//! corrected to `z - bias(u, v)`. The field is fitted from the sensor's own stream
//! (`flowfilter calibrate-depth`): where one view predicts another's depth, the differences
//! that follow the pixel, not the scene, are the field.

use flowfilter_geometry::RawDepth;
use serde::{Deserialize, Serialize};

/// The most grid cells a side (a field finer than 1/8 of a 1024-pixel image is noise).
pub const MAX_BIAS_CELLS: usize = 128;

/// The largest correction accepted, metres (a field beyond it is a wrong file, not a sensor).
pub const MAX_BIAS_M: f64 = 0.1;

/// A depth camera's systematic error over its image, metres (positive: the sensor reads too far).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DepthBias {
    /// Control values across (columns of the grid).
    pub cols: usize,
    /// Control values down (rows of the grid).
    pub rows: usize,
    /// Width of the depth image the field spans, pixels.
    pub width: u32,
    /// Height of the depth image the field spans, pixels.
    pub height: u32,
    /// The control values, row-major (`rows * cols`), metres.
    pub metres: Vec<f64>,
}

/// Why a depth bias cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DepthBiasError {
    /// The grid's shape or values are not a field.
    #[error("depth bias: {0}")]
    Invalid(String),
    /// The field spans an image of another size than the depth image it is applied to.
    #[error("depth bias: the field spans a {field_w}x{field_h} depth image, the depth image is {image_w}x{image_h}")]
    Size {
        /// The field's image width.
        field_w: u32,
        /// The field's image height.
        field_h: u32,
        /// The depth image's width.
        image_w: usize,
        /// The depth image's height.
        image_h: usize,
    },
}

impl DepthBias {
    /// A field of zeros: `cols` x `rows` control values over a `width` x `height` image.
    ///
    /// # Errors
    /// [`DepthBiasError::Invalid`] for an empty or oversized grid or image.
    ///
    /// ```
    /// use flowfilter_camera::DepthBias;
    /// let mut bias = DepthBias::zeros(4, 3, 640, 480)?;
    /// bias.metres[5] = 0.002; // cell (1, 1): centred at pixel (239.5, 239.5)
    /// assert!((bias.at(239.5, 239.5) - 0.002).abs() < 1e-12);
    /// assert_eq!(bias.at(0.0, 0.0), 0.0);
    /// # Ok::<(), flowfilter_camera::DepthBiasError>(())
    /// ```
    pub fn zeros(cols: usize, rows: usize, width: u32, height: u32) -> Result<Self, DepthBiasError> {
        let bias = Self { cols, rows, width, height, metres: vec![0.0; cols * rows] };
        bias.validate()?;
        Ok(bias)
    }

    /// Check the grid's shape and values.
    ///
    /// # Errors
    /// [`DepthBiasError::Invalid`] naming what is wrong.
    pub fn validate(&self) -> Result<(), DepthBiasError> {
        let bad = |m: String| Err(DepthBiasError::Invalid(m));
        if !(1..=MAX_BIAS_CELLS).contains(&self.cols) || !(1..=MAX_BIAS_CELLS).contains(&self.rows) {
            return bad(format!("cols and rows must be 1-{MAX_BIAS_CELLS}, found {}x{}", self.cols, self.rows));
        }
        if self.width == 0 || self.height == 0 {
            return bad(format!("the image must not be empty, found {}x{}", self.width, self.height));
        }
        if self.metres.len() != self.cols * self.rows {
            return bad(format!(
                "metres must hold cols * rows = {} values, found {}",
                self.cols * self.rows,
                self.metres.len()
            ));
        }
        if let Some(v) = self.metres.iter().find(|v| !v.is_finite() || v.abs() > MAX_BIAS_M) {
            return bad(format!("every value must be finite and within {MAX_BIAS_M} m, found {v}"));
        }
        Ok(())
    }

    /// The grid position of pixel `(u, v)`: fractional column and row of the control values.
    pub fn cell_of(&self, u: f64, v: f64) -> (f64, f64) {
        let gx = (u + 0.5) * self.cols as f64 / f64::from(self.width) - 0.5;
        let gy = (v + 0.5) * self.rows as f64 / f64::from(self.height) - 0.5;
        (gx.clamp(0.0, (self.cols - 1) as f64), gy.clamp(0.0, (self.rows - 1) as f64))
    }

    /// The control values that pixel `(u, v)` reads and their bilinear weights (weights sum to 1).
    pub fn weights(&self, u: f64, v: f64) -> [(usize, f64); 4] {
        let (gx, gy) = self.cell_of(u, v);
        let (x0, y0) = (gx.floor() as usize, gy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.cols - 1), (y0 + 1).min(self.rows - 1));
        let (fx, fy) = (gx - x0 as f64, gy - y0 as f64);
        let i = |x: usize, y: usize| y * self.cols + x;
        [
            (i(x0, y0), (1.0 - fx) * (1.0 - fy)),
            (i(x1, y0), fx * (1.0 - fy)),
            (i(x0, y1), (1.0 - fx) * fy),
            (i(x1, y1), fx * fy),
        ]
    }

    /// The bias at pixel `(u, v)`, metres.
    pub fn at(&self, u: f64, v: f64) -> f64 {
        self.weights(u, v).iter().map(|&(i, w)| w * self.metres[i]).sum()
    }

    /// This field and `other` together (a field fitted on frames already corrected by this one).
    ///
    /// # Errors
    /// [`DepthBiasError::Invalid`] when the two grids differ in shape or image.
    pub fn plus(&self, other: &DepthBias) -> Result<DepthBias, DepthBiasError> {
        let shape = |b: &DepthBias| (b.cols, b.rows, b.width, b.height);
        if shape(self) != shape(other) {
            return Err(DepthBiasError::Invalid(format!(
                "a {}x{} grid over {}x{} cannot be added to a {}x{} grid over {}x{}",
                other.cols, other.rows, other.width, other.height, self.cols, self.rows, self.width, self.height
            )));
        }
        let metres = self.metres.iter().zip(&other.metres).map(|(a, b)| a + b).collect();
        Ok(DepthBias { metres, ..self.clone() })
    }

    /// The largest correction, metres.
    pub fn max_abs(&self) -> f64 {
        self.metres.iter().fold(0.0, |m, v| m.max(v.abs()))
    }

    /// Correct raw depth in place: every reading `z` (raw units of `metres_per_unit`) becomes
    /// `z - bias`, rounded to the nearest unit; readings of 0 stay 0 and a corrected reading
    /// stays at least 1 unit.
    ///
    /// # Errors
    /// [`DepthBiasError::Size`] when `depth` is not the size the field spans.
    pub fn correct(&self, depth: &mut RawDepth, metres_per_unit: f64) -> Result<(), DepthBiasError> {
        let (w, h) = (depth.width(), depth.height());
        if (w, h) != (self.width as usize, self.height as usize) {
            return Err(DepthBiasError::Size { field_w: self.width, field_h: self.height, image_w: w, image_h: h });
        }
        for y in 0..h {
            for x in 0..w {
                let z = depth.at_mut(x, y);
                if *z != 0 {
                    let units = f64::from(*z) - self.at(x as f64, y as f64) / metres_per_unit;
                    *z = units.round().clamp(1.0, f64::from(u16::MAX)) as u16;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_field_is_bilinear_between_cell_centres_and_flat_beyond_them() {
        let mut b = DepthBias::zeros(2, 2, 40, 20).unwrap();
        b.metres = vec![0.0, 0.004, 0.002, 0.006];
        // Cell centres at u = 9.5, 29.5 and v = 4.5, 14.5.
        assert!((b.at(9.5, 4.5) - 0.0).abs() < 1e-12);
        assert!((b.at(29.5, 14.5) - 0.006).abs() < 1e-12);
        assert!((b.at(19.5, 9.5) - 0.003).abs() < 1e-12);
        assert!((b.at(0.0, 0.0) - 0.0).abs() < 1e-12);
        assert!((b.at(39.0, 0.0) - 0.004).abs() < 1e-12);
        let w: f64 = b.weights(13.0, 7.0).iter().map(|p| p.1).sum();
        assert!((w - 1.0).abs() < 1e-12);
    }

    #[test]
    fn correcting_moves_readings_and_keeps_holes() {
        let mut b = DepthBias::zeros(1, 1, 4, 2).unwrap();
        b.metres[0] = 0.003;
        let mut d = RawDepth::from_fn(4, 2, |x, _| if x == 0 { 0 } else { 500 });
        b.correct(&mut d, 0.001).unwrap();
        assert_eq!(d.as_slice(), &[0, 497, 497, 497, 0, 497, 497, 497]);
        let mut other = RawDepth::from_fn(3, 2, |_, _| 500);
        assert!(matches!(b.correct(&mut other, 0.001), Err(DepthBiasError::Size { .. })));
    }

    #[test]
    fn fields_of_one_grid_add_up() {
        let mut a = DepthBias::zeros(2, 1, 4, 2).unwrap();
        a.metres = vec![0.001, -0.002];
        let mut b = a.clone();
        b.metres = vec![0.003, 0.001];
        assert_eq!(a.plus(&b).unwrap().metres, vec![0.004, -0.001]);
        let other = DepthBias::zeros(1, 1, 4, 2).unwrap();
        assert!(a.plus(&other).unwrap_err().to_string().contains("1x1 grid"));
    }

    #[test]
    fn bad_grids_are_refused() {
        assert!(DepthBias::zeros(0, 3, 640, 480).is_err());
        assert!(DepthBias::zeros(3, 3, 0, 480).is_err());
        let mut b = DepthBias::zeros(2, 2, 640, 480).unwrap();
        b.metres[1] = f64::NAN;
        assert!(b.validate().unwrap_err().to_string().contains("finite"));
        b.metres = vec![0.0; 3];
        assert!(b.validate().unwrap_err().to_string().contains("4 values"));
    }
}
