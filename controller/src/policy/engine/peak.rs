//! This core's arithmetic peak for an instruction set: how many single-precision
//! multiply-adds a second it completes when it does nothing else, measured rather than
//! looked up (a VM's clock, its turbo and how many multiply units its cores have are not in
//! any table we could keep).
//!
//! No convolution or dense layer runs faster than this, so with a network's count
//! ([`super::CompiledNetwork::multiply_adds`]) it turns into a lower bound on a forward
//! pass's time, and a measured pass into a fraction of what the hardware allows: the figure
//! that says whether a speed target is still a matter of better kernels or is beyond the
//! machine (`dribble-controller forward` prints both).
//!
//! The probe keeps independent chains of `acc = acc * m + a` in registers, enough of them
//! that their latency is hidden and only the multiply and add units' throughput counts:
//! fused multiply-adds where the set has them, a multiply and an add on the SSE sets (as the
//! engine's SSE kernels do). Each measurement runs for about a millisecond; the best of
//! several is kept, since other work on the machine only ever slows one down.

use std::hint::black_box;
use std::time::{Duration, Instant};

use super::Isa;

/// How long one measurement should run at least.
const MEASUREMENT: Duration = Duration::from_millis(1);
/// Measurements of which the fastest counts: enough that on a shared machine one of them
/// runs undisturbed (forty still read a fifth low now and then on a busy VM).
const MEASUREMENTS: usize = 100;

/// Single-precision multiply-adds a second that one core completes with `isa`'s vector
/// instructions (lanes counted: one AVX2 fused multiply-add is eight), or `None` for the
/// portable set, which has no vector code of its own, or a set this CPU does not run.
pub fn multiply_adds_per_second(isa: Isa) -> Option<f64> {
    if !isa.is_available() {
        return None;
    }
    measure(probe_of(isa)?)
}

/// Unsigned-by-signed 8-bit multiply-adds a second that one core completes with the int8
/// kernels' sequence for `isa` (`pmaddubsw`, `pmaddwd` with ones, `paddd`: the products of
/// one quad into 32-bit sums, as [`super::kernels::int8`] computes without VNNI), lanes
/// counted (one AVX2 `vpmaddubsw` is 32 products); `None` below SSSE3. Each chain feeds
/// its sums back as the next bytes, so no step can be hoisted out of the loop; the chains'
/// latency is hidden on x86-64 (twelve of them), not quite on the 32-bit build (five).
pub fn int8_multiply_adds_per_second(isa: Isa) -> Option<f64> {
    if !isa.is_available() {
        return None;
    }
    let probe: Probe = match isa {
        Isa::Portable | Isa::Sse2 => return None,
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        Isa::Ssse3 | Isa::Sse42 => (x86::INT8_CHAINS * 16, x86::ssse3_int8_probe),
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        Isa::Avx2Fma | Isa::Avx512 => (x86::INT8_CHAINS * 32, x86::avx2_int8_probe),
        #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
        _ => return None,
    };
    measure(probe)
}

/// The fastest of [`MEASUREMENTS`] runs of `probe`, in multiply-adds a second.
fn measure((chains_lanes, probe): Probe) -> Option<f64> {
    let mut rounds = 1_000u64;
    loop {
        let started = Instant::now();
        black_box(probe(rounds));
        if started.elapsed() >= MEASUREMENT || rounds >= 1 << 40 {
            break;
        }
        rounds *= 2;
    }
    let fastest = (0..MEASUREMENTS)
        .map(|_| {
            let started = Instant::now();
            black_box(probe(rounds));
            started.elapsed()
        })
        .min()?;
    Some((rounds * chains_lanes as u64) as f64 / fastest.as_secs_f64().max(1e-9))
}

/// A probe: how many multiply-adds one round does, and the function that runs `rounds`
/// rounds and returns a value computed from all the chains (so that none is left out).
type Probe = (usize, fn(u64) -> f32);

/// The probe for `isa`.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
fn probe_of(isa: Isa) -> Option<Probe> {
    match isa {
        Isa::Portable => None,
        Isa::Sse2 | Isa::Ssse3 | Isa::Sse42 => Some((x86::SSE_CHAINS * 4, x86::sse_probe)),
        Isa::Avx2Fma => Some((x86::AVX_CHAINS * 8, x86::avx2_fma_probe)),
        Isa::Avx512 => Some((x86::AVX512_CHAINS * 16, x86::avx512_probe)),
    }
}

#[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
fn probe_of(_: Isa) -> Option<Probe> {
    None
}

#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[allow(unsafe_code)]
mod x86 {
    #[cfg(target_arch = "x86")]
    use std::arch::x86::*;
    #[cfg(target_arch = "x86_64")]
    use std::arch::x86_64::*;
    use std::hint::black_box;

    use super::super::kernels::simd::{Avx, Avx512, Sse, Vector};

    /// Chains held in registers: a multiply and a dependent add take about eight cycles on
    /// the machines we met, so fourteen chains keep three units busy on x86-64's sixteen
    /// registers (two hold `m` and `a`); six fit the 32-bit build's eight.
    pub(super) const SSE_CHAINS: usize = if cfg!(target_arch = "x86_64") { 14 } else { 6 };
    /// Twelve fused chains of four cycles keep two units busy with room to spare.
    pub(super) const AVX_CHAINS: usize = if cfg!(target_arch = "x86_64") { 12 } else { 6 };
    pub(super) const AVX512_CHAINS: usize = if cfg!(target_arch = "x86_64") { 24 } else { 6 };

    /// int8 chains: two registers hold the weights and the ones.
    pub(super) const INT8_CHAINS: usize = if cfg!(target_arch = "x86_64") { 12 } else { 5 };

    pub(super) fn ssse3_int8_probe(rounds: u64) -> f32 {
        // SAFETY: only where `Isa::Ssse3` or a wider set is available.
        unsafe { ssse3_int8(rounds) }
    }

    pub(super) fn avx2_int8_probe(rounds: u64) -> f32 {
        // SAFETY: only where `Isa::Avx2Fma` or `Isa::Avx512` is available (AVX2 included).
        unsafe { avx2_int8(rounds) }
    }

    #[target_feature(enable = "ssse3")]
    fn ssse3_int8(rounds: u64) -> f32 {
        let (w, ones) = (_mm_set1_epi8(black_box(3)), _mm_set1_epi16(1));
        let mut chains = [_mm_set1_epi32(black_box(0x0102_0304)); INT8_CHAINS];
        for _ in 0..rounds {
            for chain in &mut chains {
                let pairs = _mm_maddubs_epi16(*chain, w);
                *chain = _mm_add_epi32(*chain, _mm_madd_epi16(pairs, ones));
            }
        }
        let sum = chains
            .iter()
            .fold(_mm_setzero_si128(), |s, &c| _mm_xor_si128(s, c));
        _mm_cvtsi128_si32(sum) as f32
    }

    #[target_feature(enable = "avx2")]
    fn avx2_int8(rounds: u64) -> f32 {
        let (w, ones) = (_mm256_set1_epi8(black_box(3)), _mm256_set1_epi16(1));
        let mut chains = [_mm256_set1_epi32(black_box(0x0102_0304)); INT8_CHAINS];
        for _ in 0..rounds {
            for chain in &mut chains {
                let pairs = _mm256_maddubs_epi16(*chain, w);
                *chain = _mm256_add_epi32(*chain, _mm256_madd_epi16(pairs, ones));
            }
        }
        let sum = chains
            .iter()
            .fold(_mm256_setzero_si256(), |s, &c| _mm256_xor_si256(s, c));
        _mm256_cvtsi256_si32(sum) as f32
    }

    /// The factor and addend of every chain: the values settle near 1, far from overflow
    /// and from subnormals, whose slow paths would not measure the units.
    const M: f32 = 0.999;
    const A: f32 = 0.001;

    pub(super) fn sse_probe(rounds: u64) -> f32 {
        // SAFETY: SSE2 is the baseline of both x86 targets this crate builds for.
        unsafe { sse(rounds) }
    }

    pub(super) fn avx2_fma_probe(rounds: u64) -> f32 {
        // SAFETY: `multiply_adds_per_second` calls this only where `Isa::Avx2Fma` is
        // available, which means AVX, AVX2 and FMA.
        unsafe { avx2_fma(rounds) }
    }

    pub(super) fn avx512_probe(rounds: u64) -> f32 {
        // SAFETY: only where `Isa::Avx512` is available (AVX-512F with AVX2 and FMA).
        unsafe { avx512(rounds) }
    }

    /// `CHAINS` chains of `V`'s multiply-add for `rounds` rounds; their sum's first lane,
    /// so that nothing is optimised away.
    #[inline(always)]
    fn float_chains<V: Vector, const CHAINS: usize>(rounds: u64) -> f32 {
        let (m, a) = (V::splat(black_box(M)), V::splat(black_box(A)));
        let mut chains = [V::zero(); CHAINS];
        for _ in 0..rounds {
            for chain in &mut chains {
                *chain = V::mul_add(*chain, m, a);
            }
        }
        let sum = chains.iter().fold(V::zero(), |s, &c| V::add(s, c));
        let mut lanes = [0.0; 16];
        sum.store(&mut lanes[..V::LANES]);
        lanes[0]
    }

    #[target_feature(enable = "sse2")]
    fn sse(rounds: u64) -> f32 {
        float_chains::<Sse, SSE_CHAINS>(rounds)
    }

    #[target_feature(enable = "avx,avx2,fma")]
    fn avx2_fma(rounds: u64) -> f32 {
        float_chains::<Avx, AVX_CHAINS>(rounds)
    }

    #[target_feature(enable = "avx,avx2,fma,avx512f")]
    fn avx512(rounds: u64) -> f32 {
        float_chains::<Avx512, AVX512_CHAINS>(rounds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_vector_set_this_cpu_runs_has_a_peak_and_the_portable_one_none() {
        assert_eq!(multiply_adds_per_second(Isa::Portable), None);
        for isa in Isa::available().filter(|&isa| isa != Isa::Portable) {
            let peak = multiply_adds_per_second(isa).unwrap_or_else(|| panic!("{isa}"));
            // Any CPU that runs these sets does more than 10 M and less than a tera
            // multiply-adds a second on one core: a wrong count of lanes or rounds, or a
            // probe the compiler folded away, lands outside.
            assert!((1e7..1e12).contains(&peak), "{isa}: {peak:e}");
        }
    }

    #[test]
    fn every_set_from_ssse3_on_has_an_int8_peak() {
        for isa in Isa::available() {
            let peak = int8_multiply_adds_per_second(isa);
            match isa {
                Isa::Portable | Isa::Sse2 => assert_eq!(peak, None),
                _ => {
                    let peak = peak.unwrap_or_else(|| panic!("{isa}"));
                    assert!((1e7..1e13).contains(&peak), "{isa}: {peak:e}");
                }
            }
        }
    }

    #[test]
    fn the_probes_compute_the_chains_they_count() {
        // After n rounds every chain holds the same value x_n, x_{k+1} = M x_k + A from 0;
        // the probe returns one lane of their sum.
        let chain = |rounds: u64| (0..rounds).fold(0.0f32, |x, _| x * 0.999 + 0.001);
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        for isa in Isa::available() {
            let Some((lanes, probe)) = probe_of(isa) else {
                continue;
            };
            let summed = match isa {
                Isa::Avx512 => lanes / 16,
                Isa::Avx2Fma => lanes / 8,
                _ => lanes / 4,
            };
            let expected = chain(50) * summed as f32;
            let got = probe(50);
            assert!(
                (got - expected).abs() <= 1e-4 * expected,
                "{isa}: {got} against {expected}"
            );
        }
    }
}
