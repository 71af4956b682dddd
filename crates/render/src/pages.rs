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

/// Freed buffers smaller than this are not kept for the next frame.
const MIN_KEEP_BYTES: usize = 256 << 10;

/// A kept buffer is handed out only for a request of at least this fraction of its capacity:
/// a small request (the photon pass's lanes, 1.1 MB on the bench cumulus) given a large kept
/// buffer (a lattice path's 8 MB) left the large request that came next to map and clear fresh
/// pages, frame after frame.
const MIN_FILL: usize = 2;

/// `len` zeros of `T` (`zero`, the type's zero, allocated zeroed), with the buffer's whole
/// 2 MiB pages advised to be huge pages before anything touches them.
pub fn zeroed<T: Copy>(zero: T, len: usize) -> Vec<T> {
    let v = vec![zero; len];
    advise_huge(&v);
    v
}

/// Freed large buffers of one element type kept for the next frame, up to a number of bytes.
struct Pool<T> {
    kept: std::sync::Mutex<Vec<Vec<T>>>,
    max_bytes: usize,
}

impl<T> Pool<T> {
    const fn new(max_bytes: usize) -> Self {
        Self {
            kept: std::sync::Mutex::new(Vec::new()),
            max_bytes,
        }
    }

    /// The smallest kept buffer that holds `len` values and no more than [`MIN_FILL`] times
    /// as many, taken out of the pool.
    fn take(&self, len: usize) -> Option<Vec<T>> {
        let mut kept = self.kept.lock().ok()?;
        let best = kept
            .iter()
            .enumerate()
            .filter(|(_, v)| v.capacity() >= len && v.capacity() / MIN_FILL <= len)
            .min_by_key(|(_, v)| v.capacity())
            .map(|(i, _)| i)?;
        Some(kept.swap_remove(best))
    }

    /// Keeps `v` while the kept buffers stay within the pool's bytes (else it is freed); small
    /// buffers are freed.
    fn give_back(&self, v: Vec<T>) {
        let size = std::mem::size_of::<T>();
        let bytes = v.capacity() * size;
        if bytes < MIN_KEEP_BYTES {
            return;
        }
        if let Ok(mut kept) = self.kept.lock() {
            let held: usize = kept.iter().map(|b| b.capacity() * size).sum();
            if held + bytes <= self.max_bytes {
                kept.push(v);
            }
        }
    }
}

/// Freed `f32` working buffers [`take_f32`] and [`take_zeroed_f32`] reuse: up to 288 MB (the
/// bench's standard frame: the 14 lattice paths, 112 MB, the camera's voxel records, 40 MB, the
/// sun's paths and their layer order, 2 × 8 MB, the photon pass's 16 lanes, for the cells that
/// hold cloud only, 1.1 MB each there, and the once-scattered tally's, 0.4 MB each).
static POOL_F32: Pool<f32> = Pool::new(288 << 20);

/// `len` values whose contents are unspecified, for a buffer the caller fills completely
/// before reading any of it: one given back earlier when one is large enough (its pages are
/// mapped, and nothing is cleared: a frame's fresh buffers were mapped and zeroed by the
/// kernel, page by page, only to be overwritten), else a new [`zeroed`] one. (In this
/// crate's unit tests a reused buffer is filled with NaN, so a value left unwritten shows.)
pub fn take_f32(len: usize) -> Vec<f32> {
    match POOL_F32.take(len) {
        Some(mut v) => {
            // Within the capacity: only a grown tail is written.
            v.resize(len, 0.0);
            v.truncate(len);
            if cfg!(test) {
                v.fill(f32::NAN);
            }
            v
        }
        None => zeroed(0f32, len),
    }
}

/// `len` zeros of `f32`: a buffer of [`take_f32`]'s pool zeroed in place when one is large
/// enough (its pages are already mapped, and zeroing them in place costs less than mapping and
/// clearing fresh pages, frame after frame; measured on the warm bench frame), else a new
/// [`zeroed`] one.
pub fn take_zeroed_f32(len: usize) -> Vec<f32> {
    match POOL_F32.take(len) {
        Some(mut v) => {
            v.clear();
            v.resize(len, 0.0);
            v
        }
        None => zeroed(0f32, len),
    }
}

/// Keeps `v` for [`take_f32`] and [`take_zeroed_f32`] while the kept buffers stay within the
/// pool's 288 MB (else it is freed); small buffers are freed.
pub fn give_back_f32(v: Vec<f32>) {
    POOL_F32.give_back(v);
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

    /// A zeroed `f32` buffer given back and taken again holds zeros of the new length.
    #[test]
    fn reused_zeroed_f32_buffers_are_zero() {
        let len = (5 << 20) / 4;
        let mut v = take_zeroed_f32(len);
        v.iter_mut().for_each(|x| *x = 2.0);
        give_back_f32(v);
        for n in [len - 3, len, len + 5] {
            let w = take_zeroed_f32(n);
            assert_eq!(w.len(), n);
            assert!(w.iter().all(|&x| x == 0.0));
            give_back_f32(w);
        }
    }

    /// A working buffer given back is taken again at the asked length (contents unspecified:
    /// NaN in these tests), and a larger request than any kept buffer gets a fresh one.
    #[test]
    fn reused_f32_buffers_have_the_length() {
        let len = (5 << 20) / 4;
        let mut v = take_f32(len);
        v.iter_mut().for_each(|x| *x = 2.0);
        give_back_f32(v);
        for n in [len - 3, len, 4 * len] {
            let w = take_f32(n);
            assert_eq!(w.len(), n);
            assert!(w.iter().all(|&x| x.is_nan() || x == 0.0));
            give_back_f32(w);
        }
    }

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
