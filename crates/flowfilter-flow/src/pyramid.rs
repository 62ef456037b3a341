//! Image pyramids for the window matcher, built once per image and crop and shared by every
//! tracking pass that reads them (a pair's forward and backward tracks, its plain and guided
//! passes, the judge's re-track).

use crate::lk::{Gray, central_gradients, downsample};
use rayon::prelude::*;
use std::sync::{Arc, Mutex, OnceLock};

/// An image's Gaussian pyramid (level 0 the image, each next level [`downsample`]d by 2) and,
/// once asked for, each level's [`central_gradients`].
pub struct ImagePyramid {
    levels: Vec<Gray>,
    gradients: OnceLock<Vec<(Gray, Gray)>>,
}

impl std::fmt::Debug for ImagePyramid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let dims: Vec<(usize, usize)> = self.levels.iter().map(Gray::dims).collect();
        f.debug_struct("ImagePyramid").field("levels", &dims).finish()
    }
}

impl ImagePyramid {
    /// `image` and `levels` levels above it.
    ///
    /// ```
    /// use flowfilter_flow::lk::Gray;
    /// use flowfilter_flow::pyramid::ImagePyramid;
    ///
    /// let pyramid = ImagePyramid::new(Gray::filled(64, 48, 0.5), 2);
    /// assert_eq!((pyramid.depth(), pyramid.level(2).dims()), (2, (16, 12)));
    /// ```
    pub fn new(image: Gray, levels: usize) -> Self {
        let mut all = Vec::with_capacity(levels + 1);
        all.push(image);
        for _ in 0..levels {
            let next = downsample(all.last().expect("level 0 is there"));
            all.push(next);
        }
        Self { levels: all, gradients: OnceLock::new() }
    }

    /// Levels above the image.
    pub fn depth(&self) -> usize {
        self.levels.len() - 1
    }

    /// Level `k` (0: the image). Panics beyond [`ImagePyramid::depth`].
    pub fn level(&self, k: usize) -> &Gray {
        &self.levels[k]
    }

    /// Every level, the image first.
    pub fn levels(&self) -> &[Gray] {
        &self.levels
    }

    /// Every level's central-difference gradients `(d/dx, d/dy)`, computed when first asked for.
    /// No lock is held while computing (the levels run as rayon jobs, and a worker waiting on
    /// them may take up another track of the same pyramid): threads that race compute the same
    /// values, and the first stored is kept.
    pub fn gradients(&self) -> &[(Gray, Gray)] {
        if let Some(g) = self.gradients.get() {
            return g;
        }
        let computed: Vec<(Gray, Gray)> = self.levels.par_iter().map(central_gradients).collect();
        self.gradients.get_or_init(|| computed)
    }
}

/// Where a pyramid was cut from its frame's image, and how deep it is: what a cached pyramid is
/// found by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PyramidKey {
    /// The crop's top-left pixel...
    pub x0: usize,
    /// ...
    pub y0: usize,
    /// ... and its size.
    pub width: usize,
    /// ...
    pub height: usize,
    /// Levels above the crop.
    pub levels: usize,
}

/// Pyramids kept per frame: the last [`PyramidCache::KEPT`] crops asked for.
#[derive(Default)]
pub struct PyramidCache {
    kept: Mutex<Vec<(PyramidKey, Arc<ImagePyramid>)>>,
}

impl std::fmt::Debug for PyramidCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let keys: Vec<PyramidKey> = self.lock().iter().map(|(k, _)| *k).collect();
        f.debug_struct("PyramidCache").field("kept", &keys).finish()
    }
}

impl PyramidCache {
    /// Pyramids kept: a pair cuts each of its frames to one crop, read by all its passes; a
    /// second one serves a frame that two pairs read at once (each pair lets its frames'
    /// pyramids go when it ends).
    pub const KEPT: usize = 2;

    /// The pyramid of `key`: the kept one, or `build`'s (kept in place of the oldest). `build`
    /// runs without the lock held; a pyramid another thread stored meanwhile is returned instead.
    pub fn pyramid(&self, key: PyramidKey, build: impl FnOnce() -> ImagePyramid) -> Arc<ImagePyramid> {
        if let Some(found) = self.find(key) {
            return found;
        }
        let built = Arc::new(build());
        let mut kept = self.lock();
        if let Some((_, found)) = kept.iter().find(|(k, _)| *k == key) {
            return found.clone();
        }
        if kept.len() >= Self::KEPT {
            kept.remove(0);
        }
        kept.push((key, built.clone()));
        built
    }

    /// Let every kept pyramid go (the passes that shared them are done; pyramids still in use
    /// live on with their users).
    pub fn clear(&self) {
        self.lock().clear();
    }

    fn find(&self, key: PyramidKey) -> Option<Arc<ImagePyramid>> {
        self.lock().iter().find(|(k, _)| *k == key).map(|(_, p)| p.clone())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<(PyramidKey, Arc<ImagePyramid>)>> {
        // A panic elsewhere while holding the lock leaves the list whole: read it all the same.
        self.kept.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(x0: usize) -> PyramidKey {
        PyramidKey { x0, y0: 0, width: 32, height: 24, levels: 1 }
    }

    #[test]
    fn a_kept_pyramid_is_built_once() {
        let cache = PyramidCache::default();
        let builds = std::sync::atomic::AtomicUsize::new(0);
        let build = || {
            builds.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            ImagePyramid::new(Gray::filled(32, 24, 0.25), 1)
        };
        let a = cache.pyramid(key(0), build);
        let b = cache.pyramid(key(0), build);
        assert!(Arc::ptr_eq(&a, &b));
        cache.pyramid(key(1), build);
        cache.pyramid(key(2), build);
        // The oldest (x0 = 0) made way for the third crop.
        cache.pyramid(key(0), build);
        assert_eq!(builds.load(std::sync::atomic::Ordering::Relaxed), 4);
        cache.clear();
        cache.pyramid(key(0), build);
        assert_eq!(builds.load(std::sync::atomic::Ordering::Relaxed), 5);
    }

    #[test]
    fn gradients_are_the_levels_central_differences() {
        let image = Gray::from_fn(40, 30, |x, y| (x * x + 3 * y) as f32 * 0.001);
        let pyramid = ImagePyramid::new(image, 2);
        assert_eq!(pyramid.gradients().len(), 3);
        for (k, (gx, gy)) in pyramid.gradients().iter().enumerate() {
            let (ex, ey) = central_gradients(pyramid.level(k));
            assert_eq!((gx.as_slice(), gy.as_slice()), (ex.as_slice(), ey.as_slice()));
        }
    }
}
