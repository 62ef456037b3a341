//! Stable least-significant-digit radix sort of integer keys, returning the sorting
//! permutation: linear time for the packed keys of spatial orders and voxel grids, where a
//! comparison sort of `(key, index)` pairs costs several times more. Equal keys keep their
//! index order, so the result is exactly that of sorting the pairs.

/// Digit width of the passes.
const RADIX_BITS: u32 = 11;

/// `0..keys.len()` sorted by `keys` (each below `2^bits`), equal keys in index order: one
/// counting pass per `RADIX_BITS`-bit digit.
pub fn radix_order(mut keys: Vec<u64>, bits: u32) -> Vec<u32> {
    let n = keys.len();
    assert!(u32::try_from(n).is_ok(), "radix_order sorts at most 2^32 keys");
    let mut order: Vec<u32> = (0..n as u32).collect();
    let (mut order_next, mut keys_next) = (vec![0u32; n], vec![0u64; n]);
    let mask = (1u64 << RADIX_BITS) - 1;
    let mut shift = 0;
    while shift < bits.min(64) {
        let digit = |k: u64| ((k >> shift) & mask) as usize;
        let mut start = vec![0usize; (1 << RADIX_BITS) + 1];
        for &k in &keys {
            start[digit(k) + 1] += 1;
        }
        for b in 0..1 << RADIX_BITS {
            start[b + 1] += start[b];
        }
        for (&k, &i) in keys.iter().zip(&order) {
            let at = &mut start[digit(k)];
            (keys_next[*at], order_next[*at]) = (k, i);
            *at += 1;
        }
        std::mem::swap(&mut keys, &mut keys_next);
        std::mem::swap(&mut order, &mut order_next);
        shift += RADIX_BITS;
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The permutation of a comparison sort of `(key, index)` pairs, for keys of several widths
    /// (one pass, several, all 64 bits), repeated keys, and no keys.
    #[test]
    fn radix_order_is_the_pair_sort() {
        let mut s = 3u64;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            s
        };
        for bits in [1u32, 7, 11, 12, 30, 45, 64] {
            let keys: Vec<u64> = (0..2000).map(|_| if bits == 64 { next() } else { next() >> (64 - bits) }).collect();
            let mut pairs: Vec<(u64, u32)> = keys.iter().enumerate().map(|(i, &k)| (k, i as u32)).collect();
            pairs.sort_unstable();
            let want: Vec<u32> = pairs.into_iter().map(|(_, i)| i).collect();
            assert_eq!(radix_order(keys, bits), want, "{bits} bits");
        }
        assert!(radix_order(vec![], 10).is_empty());
    }
}
