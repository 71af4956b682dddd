//! Randomised quasi-Monte Carlo points for the photons' first steps: the Sobol' sequence
//! (Sobol' 1967) with the direction numbers of Joe & Kuo (2008, "Constructing Sobol sequences
//! with better two-dimensional projections", the file new-joe-kuo-6.21201), each dimension
//! Owen-scrambled (Owen 1995) by the hash of Laine & Karras as Burley (2020, "Practical
//! Hash-based Owen Scrambling", JCGT 9(4)) gives it. With a uniform random seed each point is
//! uniform (the scramble starts with a uniform shift of the 32-bit integer and continues with
//! bijections), so every estimate stays unbiased, and the points keep the sequence's net
//! structure (the scramble flips each bit as a function of the bits above it only).

/// Dimensions available.
pub const DIMS: usize = 8;

/// Joe & Kuo's (s, a, m₁…m_s) for dimensions 2 … [`DIMS`] (the first is the van der Corput
/// sequence in base 2).
const JOE_KUO: [(u32, u32, &[u32]); DIMS - 1] = [
    (1, 0, &[1]),
    (2, 1, &[1, 3]),
    (3, 1, &[1, 3, 1]),
    (3, 2, &[1, 1, 1]),
    (4, 1, &[1, 1, 3, 3]),
    (4, 4, &[1, 3, 5, 13]),
    (5, 2, &[1, 1, 5, 5, 17]),
];

/// The generator matrices' columns (direction numbers v_k, 32 bits) and one scramble seed per
/// dimension.
pub struct Sobol {
    v: [[u32; 32]; DIMS],
    seeds: [u32; DIMS],
}

impl Sobol {
    /// The sequence scrambled by `seeds` (one per dimension; uniform random for unbiased
    /// points).
    pub fn new(seeds: [u32; DIMS]) -> Self {
        let mut v = [[0u32; 32]; DIMS];
        for (k, x) in v[0].iter_mut().enumerate() {
            *x = 1 << (31 - k);
        }
        for (d, &(s, a, m)) in JOE_KUO.iter().enumerate() {
            let s = s as usize;
            let col = &mut v[d + 1];
            for k in 0..32 {
                col[k] = if k < s {
                    m[k] << (31 - k)
                } else {
                    let mut x = col[k - s] ^ (col[k - s] >> s);
                    for j in 1..s {
                        if (a >> (s - 1 - j)) & 1 == 1 {
                            x ^= col[k - j];
                        }
                    }
                    x
                };
            }
        }
        Self { v, seeds }
    }

    /// The unscrambled point `i` in Gray-code order (Antonov & Saleev 1979: the first 2^m
    /// points are the sequence's first 2^m), dimension `d` (< [`DIMS`]).
    #[inline]
    pub fn raw(&self, i: u32, d: usize) -> u32 {
        let mut x = 0u32;
        let mut n = i ^ (i >> 1);
        let mut k = 0;
        while n != 0 {
            if n & 1 == 1 {
                x ^= self.v[d][k];
            }
            n >>= 1;
            k += 1;
        }
        x
    }

    /// Point `i` from point `i − 1` (`raw`, Gray-code order): one direction number.
    #[inline]
    pub fn next_raw(&self, raw: u32, i: u32, d: usize) -> u32 {
        raw ^ self.v[d][i.trailing_zeros() as usize]
    }

    /// The scrambled coordinate of a `raw` value in dimension `d`, in (0, 1).
    #[inline]
    pub fn scramble(&self, raw: u32, d: usize) -> f64 {
        // Owen scrambling by the Laine-Karras hash on the bit-reversed value (Burley 2020).
        let y = laine_karras(raw.reverse_bits(), self.seeds[d]).reverse_bits();
        // The 32-bit value's centre.
        (y as f64 + 0.5) * (1.0 / 4_294_967_296.0)
    }

    /// Point `i`'s coordinate in dimension `d` (Gray-code order), in (0, 1).
    #[cfg(test)]
    pub fn get(&self, i: u32, d: usize) -> f64 {
        self.scramble(self.raw(i, d), d)
    }
}

/// Laine & Karras's permutation (as Burley 2020, listing 1): each output bit depends on the
/// input bits below it only.
#[inline]
fn laine_karras(mut x: u32, seed: u32) -> u32 {
    x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The quality parameter t of the first 2^m points' projection on dimensions (a, b): the
    /// smallest t such that every elementary box of volume 2^(t − m) (2^k × 2^(m − t − k)
    /// intervals) holds 2^t points (Niederreiter 1992, ch. 4).
    fn t_value(s: &Sobol, a: usize, b: usize, m: u32) -> u32 {
        let n = 1u32 << m;
        let pts: Vec<(f64, f64)> = (0..n).map(|i| (s.get(i, a), s.get(i, b))).collect();
        (0..=m)
            .find(|&t| {
                (0..=m - t).all(|k| {
                    let (nx, ny) = (1usize << k, 1usize << (m - t - k));
                    let mut count = vec![0u32; nx * ny];
                    for &(x, y) in &pts {
                        count[(x * nx as f64) as usize * ny + (y * ny as f64) as usize] += 1;
                    }
                    count.iter().all(|&c| c == 1 << t)
                })
            })
            .unwrap()
    }

    #[test]
    fn projections_are_nets_of_small_quality_parameter() {
        // Sobol' points are (t, m, 2)-nets in every pair of dimensions; the first two form a
        // (0, m, 2)-net (Sobol' 1967), and Joe & Kuo chose the others' direction numbers for
        // small t in two dimensions; a mistaken direction number or recurrence (a polynomial
        // that is not primitive) gives t near m (here 10). Owen scrambling keeps the net
        // (Owen 1995).
        for seeds in [[0u32; DIMS], [0x9E37_79B9, 7, 11, 13, 17, 19, 23, 29]] {
            let s = Sobol::new(seeds);
            assert_eq!(t_value(&s, 0, 1, 10), 0);
            for a in 0..DIMS {
                for b in a + 1..DIMS {
                    let t = t_value(&s, a, b, 10);
                    assert!(t <= 4, "dims {a}, {b}: t = {t}");
                }
            }
        }
    }

    #[test]
    fn the_points_follow_one_another_by_one_direction_number() {
        let s = Sobol::new([5; DIMS]);
        for d in 0..DIMS {
            let mut x = s.raw(1000, d);
            for i in 1001..1200 {
                x = s.next_raw(x, i, d);
                assert_eq!(x, s.raw(i, d));
            }
        }
    }

    #[test]
    fn each_dimension_is_a_stratification_of_the_unit_interval() {
        // Any 2^m consecutive-from-zero points hold one point in each interval of width 2^−m.
        let s = Sobol::new([3, 1, 4, 1, 5, 9, 2, 6]);
        for d in 0..DIMS {
            let mut hit = [false; 256];
            for i in 0..256 {
                hit[(s.get(i, d) * 256.0) as usize] = true;
            }
            assert!(hit.iter().all(|&h| h), "dimension {d}");
        }
    }
}
