//! Row-major 2-D rasters: masks, depth maps, flow components.

use serde::{Deserialize, Serialize};

/// A row-major raster of `width x height` cells (`data[y * width + x]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grid<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

/// Object mask: `true` where the object is.
pub type Mask = Grid<bool>;
/// Raw sensor depth (device units; 0 = no reading).
pub type RawDepth = Grid<u16>;
/// Metric depth in metres (0 or NaN = no depth, as documented by the producer).
pub type DepthMap = Grid<f32>;

/// A buffer whose length does not match the stated raster size.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("raster of {width}x{height} needs {} cells, buffer has {found}", width * height)]
pub struct GridSizeError {
    /// Stated width.
    pub width: usize,
    /// Stated height.
    pub height: usize,
    /// Buffer length found.
    pub found: usize,
}

impl<T: Clone> Grid<T> {
    /// A raster filled with `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self { width, height, data: vec![value; width * height] }
    }

    /// The `width x height` window whose top-left cell is `(x0, y0)`, copied row by row.
    ///
    /// # Panics
    /// When the window does not lie inside the grid.
    ///
    /// ```
    /// use flowfilter_geometry::Grid;
    /// let g = Grid::from_fn(4, 3, |x, y| 10 * y + x);
    /// let c = g.crop(1, 1, 2, 2);
    /// assert_eq!(c.as_slice(), &[11, 12, 21, 22]);
    /// ```
    pub fn crop(&self, x0: usize, y0: usize, width: usize, height: usize) -> Self {
        assert!(x0 + width <= self.width && y0 + height <= self.height, "crop outside the grid");
        let mut data = Vec::with_capacity(width * height);
        for y in y0..y0 + height {
            data.extend_from_slice(&self.row(y)[x0..x0 + width]);
        }
        Self { width, height, data }
    }
}

impl<T> Grid<T> {
    /// Wrap a row-major buffer.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self, GridSizeError> {
        if data.len() != width * height {
            return Err(GridSizeError { width, height, found: data.len() });
        }
        Ok(Self { width, height, data })
    }

    /// Build from a function of `(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self { width, height, data }
    }

    /// Width (columns).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height (rows).
    pub fn height(&self) -> usize {
        self.height
    }

    /// `(width, height)`.
    pub fn dims(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The row-major cells.
    pub fn as_slice(&self) -> &[T] {
        &self.data
    }

    /// The row-major cells, mutable.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// The buffer.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// Cell `(x, y)`, `None` outside.
    pub fn get(&self, x: usize, y: usize) -> Option<&T> {
        (x < self.width && y < self.height).then(|| &self.data[y * self.width + x])
    }

    /// Cell `(x, y)`; panics outside (use [`Grid::get`] for untrusted coordinates).
    pub fn at(&self, x: usize, y: usize) -> &T {
        &self.data[y * self.width + x]
    }

    /// Mutable cell `(x, y)`; panics outside.
    pub fn at_mut(&mut self, x: usize, y: usize) -> &mut T {
        &mut self.data[y * self.width + x]
    }

    /// Row `y`.
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// A raster of the same size with `f` applied to every cell.
    pub fn map<U>(&self, f: impl FnMut(&T) -> U) -> Grid<U> {
        Grid { width: self.width, height: self.height, data: self.data.iter().map(f).collect() }
    }
}

impl Mask {
    /// Number of `true` cells.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }
}

/// The bounding box `(x0, y0, x1, y1)` (inclusive) of a mask's set pixels, `None` if empty.
pub fn mask_bbox(mask: &Mask) -> Option<(usize, usize, usize, usize)> {
    let mut bb: Option<(usize, usize, usize, usize)> = None;
    for y in 0..mask.height() {
        let row = mask.row(y);
        if let Some(first) = first_set(row) {
            let last = last_set(row).expect("a row with a first set pixel has a last one");
            bb = Some(match bb {
                None => (first, y, last, y),
                Some((a, b, c, _)) => (a.min(first), b, c.max(last), y),
            });
        }
    }
    bb
}

/// Mask rows are scanned in blocks of this many pixels with a branch-free OR (vectorised),
/// then the block that holds the answer is searched pixel by pixel.
const SCAN_BLOCK: usize = 64;

fn any_set(block: &[bool]) -> bool {
    block.iter().fold(false, |a, &b| a | b)
}

/// Index of the first set pixel of a row.
fn first_set(row: &[bool]) -> Option<usize> {
    let block = row.chunks(SCAN_BLOCK).position(any_set)?;
    let start = block * SCAN_BLOCK;
    row[start..].iter().position(|&b| b).map(|i| start + i)
}

/// Index of the last set pixel of a row.
fn last_set(row: &[bool]) -> Option<usize> {
    let block = row.chunks(SCAN_BLOCK).rposition(any_set)?;
    let start = block * SCAN_BLOCK;
    let end = (start + SCAN_BLOCK).min(row.len());
    row[start..end].iter().rposition(|&b| b).map(|i| start + i)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_bbox_matches_a_pixel_by_pixel_scan() {
        // Widths around the scan block size; set pixels in first, middle and partial last blocks.
        let mut seed = 5u64;
        for (w, h) in [(1, 1), (63, 3), (64, 2), (65, 4), (200, 7), (1280, 5)] {
            for _ in 0..20 {
                let mask = Grid::from_fn(w, h, |_, _| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (seed >> 33).is_multiple_of(97)
                });
                let mut want: Option<(usize, usize, usize, usize)> = None;
                for y in 0..h {
                    for x in 0..w {
                        if *mask.at(x, y) {
                            want = Some(match want {
                                None => (x, y, x, y),
                                Some((a, b, c, d)) => (a.min(x), b.min(y), c.max(x), d.max(y)),
                            });
                        }
                    }
                }
                assert_eq!(mask_bbox(&mask), want, "{w}x{h}");
            }
        }
        assert_eq!(mask_bbox(&Grid::from_fn(130, 2, |x, y| x == 129 && y == 1)), Some((129, 1, 129, 1)));
    }

    #[test]
    fn indexing_is_row_major() {
        let g = Grid::from_fn(3, 2, |x, y| 10 * y + x);
        assert_eq!(g.as_slice(), &[0, 1, 2, 10, 11, 12]);
        assert_eq!(*g.at(2, 1), 12);
        assert_eq!(g.get(3, 0), None);
        assert_eq!(g.row(1), &[10, 11, 12]);
        assert!(Grid::from_vec(2, 2, vec![0u8; 3]).is_err());
        let m: Mask = g.map(|v| v % 2 == 0);
        assert_eq!(m.count(), 4);
    }
}
