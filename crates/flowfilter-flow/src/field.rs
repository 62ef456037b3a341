//! Dense flow fields.

use flowfilter_geometry::{Grid, Mask};

/// A dense flow field: for each pixel `x` of the "from" image, the displacement `f(x) = (u, v)`
/// (pixels) to the same scene point in the "to" image, and whether it is valid.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowField {
    /// Displacements `(u, v)`.
    pub flow: Grid<[f32; 2]>,
    /// Validity (false where the estimator or the data has no flow).
    pub valid: Mask,
}

impl FlowField {
    /// A field of zero flow, all valid.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self { flow: Grid::filled(width, height, [0.0; 2]), valid: Mask::filled(width, height, true) }
    }

    /// Width.
    pub fn width(&self) -> usize {
        self.flow.width()
    }

    /// Height.
    pub fn height(&self) -> usize {
        self.flow.height()
    }

    /// Flow at a pixel, `None` outside or where invalid.
    pub fn at(&self, x: usize, y: usize) -> Option<[f32; 2]> {
        (self.valid.get(x, y).copied() == Some(true)).then(|| *self.flow.at(x, y))
    }

    /// Bilinear flow at a sub-pixel position (pixel centres at integers); `None` if any of the
    /// four neighbours is outside or invalid.
    pub fn sample(&self, x: f64, y: f64) -> Option<[f32; 2]> {
        let (x0, y0) = (x.floor(), y.floor());
        if x0 < 0.0 || y0 < 0.0 {
            return None;
        }
        let (ix, iy) = (x0 as usize, y0 as usize);
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let a = self.at(ix, iy)?;
        let b = self.at(ix + 1, iy)?;
        let c = self.at(ix, iy + 1)?;
        let d = self.at(ix + 1, iy + 1)?;
        Some(std::array::from_fn(|k| {
            (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy
        }))
    }
}
