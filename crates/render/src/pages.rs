//! Large working buffers on transparent huge pages (Linux): a hint to the kernel, no change in
//! any value.
//!
//! The photon pass scatters its track lengths over accumulators of tens of MB at random
//! places, and the pixel march reads the per-voxel records (40 MB for a 128³ cloud) a layer of
//! voxels apart at every step: with 4 KiB pages nearly every access misses the TLB, and every
//! page is faulted in (and zeroed) separately, twice for an accumulator that is first read
//! (the shared zero page, then a copy on write). Backed by 2 MiB pages (`madvise(MADV_HUGEPAGE)`
//! on a buffer not yet touched, where the system's `transparent_hugepage` setting is `madvise`
//! or `always`), both costs fall by the factor 512. Elsewhere, or when the kernel declines,
//! the buffer is an ordinary one.

/// Buffers smaller than this keep ordinary pages (a huge page would not be filled).
const MIN_BYTES: usize = 4 << 20;

/// `len` zeros of `T` (`zero`, the type's zero, allocated zeroed), with the buffer's whole
/// 2 MiB pages advised to be huge pages before anything touches them.
pub fn zeroed<T: Copy>(zero: T, len: usize) -> Vec<T> {
    let v = vec![zero; len];
    advise_huge(&v);
    v
}

/// Asks the kernel to back `buf`'s whole 2 MiB pages with huge pages (a hint: no effect on any
/// value; ignored where unsupported).
fn advise_huge<T>(buf: &[T]) {
    let bytes = std::mem::size_of_val(buf);
    if bytes < MIN_BYTES {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let start = buf.as_ptr() as usize;
        let first = start.next_multiple_of(HUGE);
        let end = (start + bytes) & !(HUGE - 1);
        if end > first {
            // SAFETY: madvise with MADV_HUGEPAGE changes no contents and no mapping's
            // permissions; the range [first, end) lies inside `buf`'s allocation and is
            // page-aligned. A failure (e.g. no transparent huge page support) is ignored.
            unsafe {
                libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The advised buffers hold zeros of the asked length, large and small, and take writes.
    #[test]
    fn zeroed_buffers_are_zero() {
        for len in [0, 3, 1 << 20, (6 << 20) / 8 + 17] {
            let mut v = zeroed(0f64, len);
            assert_eq!(v.len(), len);
            assert!(v.iter().all(|&x| x == 0.0));
            if let Some(x) = v.last_mut() {
                *x = 1.5;
                assert_eq!(v[len - 1], 1.5);
            }
        }
    }
}
