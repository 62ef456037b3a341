//! Recycled `f32` buffers for the dense estimator.
//!
//! One DIS call on a 1024x436 pair allocates some twenty megabytes of images. Allocations that
//! large come from the operating system as fresh zero pages, and the first write to each page
//! is a page fault: about 6 ms per Sintel pair on the project's machine, a sixth of the whole
//! run. Buffers are therefore handed back when an image is no longer needed and reused by the
//! next allocation of at most their size (the same sizes recur scale after scale, call after
//! call).

use std::sync::Mutex;

/// Buffers smaller than this (in values) are not worth pooling.
const MIN_POOLED: usize = 4096;
/// At most this many buffers are kept.
const MAX_POOLED: usize = 96;

static POOL: Mutex<Vec<Vec<f32>>> = Mutex::new(Vec::new());

/// A buffer of `len` zeros, reusing a pooled one when one is large enough (the smallest such).
pub(crate) fn zeroed(len: usize) -> Vec<f32> {
    let reused = if len >= MIN_POOLED {
        let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
        let best = pool
            .iter()
            .enumerate()
            .filter(|(_, b)| b.capacity() >= len)
            .min_by_key(|(_, b)| b.capacity())
            .map(|(i, _)| i);
        best.map(|i| pool.swap_remove(i))
    } else {
        None
    };
    match reused {
        Some(mut v) => {
            v.clear();
            v.resize(len, 0.0);
            v
        }
        None => vec![0.0; len],
    }
}

/// Hands a buffer back for reuse (small ones, and any beyond the pool's size, are freed).
pub(crate) fn recycle(v: Vec<f32>) {
    if v.capacity() < MIN_POOLED {
        return;
    }
    let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
    if pool.len() < MAX_POOLED {
        pool.push(v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recycled_buffers_come_back_zeroed_and_large_enough() {
        let mut a = zeroed(10_000);
        a.iter_mut().for_each(|v| *v = 7.0);
        recycle(a);
        // Other tests may use the pool concurrently: the buffer is reused unless taken first.
        let b = zeroed(9_000);
        assert_eq!(b.len(), 9_000);
        assert!(b.iter().all(|&v| v == 0.0));
        let small = zeroed(10);
        assert_eq!(small, vec![0.0; 10]);
        recycle(small);
    }
}
