//! The SSSE3 int8 kernels (the Nao V5's Atom and, with SSE4.1's `pmaxsd`, the V6's), their
//! inner loops in assembly: panels of 4, 8 and 16 outputs.
// The vector kernels are `unsafe`: intrinsics of a `#[target_feature]` the caller checked.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86")]
use std::arch::x86::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::panels::{QuadPanels, WeightBlock, write_sums};
use super::{GROUP, ZeroGroups};

/// Products of one group in assembly text, interleaved: for each `(temporary, quad, weight
/// offset, sum)`, `pshufd` spreads quad `$quad` of the group over the lanes of its own
/// temporary (also the copy `pmaddubsw` overwrites), then every `pmaddubsw` (the aligned
/// weights at `{w} + $offset` its memory operand), every `pmaddwd` with ones, every `paddd`
/// into its sum register. Four instructions a product, as one product after the other took,
/// but the products' chains side by side: the V5's Atom is in order, and one product's four
/// instructions each wait for the last (about 2.3 cycles an instruction: llvm-mca's `atom`
/// model, 47 cycles a group of a 4-wide panel one product after the other, 27 with four
/// side by side; `silvermont`, the V6's core: 44 and 22).
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! products {
    ($(($t:literal, $quad:literal, $offset:literal, $sum:literal)),+ $(,)?) => {
        concat!(
            $("pshufd {", $t, "}, {xs}, ", $quad, "\n",)+
            $("pmaddubsw {", $t, "}, xmmword ptr [{w} + ", $offset, "]\n",)+
            $("pmaddwd {", $t, "}, {ones}\n",)+
            $("paddd {", $sum, "}, {", $t, "}\n",)+
        )
    };
}

/// The first `$quads` quads (1 to 4) of one group's products for a 16-wide panel, in assembly
/// text ([`products`] into `{s0}`..`{s3}`, two side by side in `{t0}` and `{t1}`): 16
/// instructions a quad, 64 for a whole group, in all eight of the V5's registers (the sums,
/// the input, the ones, two products). Fewer than four only for a row's last group, whose
/// other quads hold nothing but padding ([`row_asm`]).
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[cfg_attr(target_arch = "x86_64", allow(unused_macros))]
macro_rules! products16 {
    (@quad $quad:literal, $o0:literal, $o1:literal, $o2:literal, $o3:literal) => {
        concat!(
            products!(("t0", $quad, $o0, "s0"), ("t1", $quad, $o1, "s1")),
            products!(("t0", $quad, $o2, "s2"), ("t1", $quad, $o3, "s3")),
        )
    };
    (1) => {
        products16!(@quad "0x00", "0", "16", "32", "48")
    };
    (2) => {
        concat!(products16!(1), products16!(@quad "0x55", "64", "80", "96", "112"))
    };
    (3) => {
        concat!(products16!(2), products16!(@quad "0xaa", "128", "144", "160", "176"))
    };
    (4) => {
        concat!(products16!(3), products16!(@quad "0xff", "192", "208", "224", "240"))
    };
}

/// [`products16`] with the four products of a quad side by side, for the V6 (x86-64's
/// sixteen vector registers: the sums, the input, the ones and four products): one `pshufd`
/// spreads the quad, three `movdqa` copy it for the other three products. On the V6's
/// Silvermont the products' multiplies and `pshufd` share one port and each multiply waits
/// five cycles for its operand: two products side by side left that port idle in between
/// (llvm-mca `silvermont`, one group: 115 cycles two side by side, 84 four, 79 with copies
/// in place of three of the four `pshufd`; the multiplies' floor is 64).
#[cfg(target_arch = "x86_64")]
macro_rules! products16_wide {
    (@quad $quad:literal, $o0:literal, $o1:literal, $o2:literal, $o3:literal) => {
        concat!(
            "pshufd {t0}, {xs}, ", $quad, "\n",
            "movdqa {t1}, {t0}\n",
            "movdqa {t2}, {t0}\n",
            "movdqa {t3}, {t0}\n",
            "pmaddubsw {t0}, xmmword ptr [{w} + ", $o0, "]\n",
            "pmaddubsw {t1}, xmmword ptr [{w} + ", $o1, "]\n",
            "pmaddubsw {t2}, xmmword ptr [{w} + ", $o2, "]\n",
            "pmaddubsw {t3}, xmmword ptr [{w} + ", $o3, "]\n",
            "pmaddwd {t0}, {ones}\n",
            "pmaddwd {t1}, {ones}\n",
            "pmaddwd {t2}, {ones}\n",
            "pmaddwd {t3}, {ones}\n",
            "paddd {s0}, {t0}\n",
            "paddd {s1}, {t1}\n",
            "paddd {s2}, {t2}\n",
            "paddd {s3}, {t3}\n",
        )
    };
    (1) => {
        products16_wide!(@quad "0x00", "0", "16", "32", "48")
    };
    (2) => {
        concat!(products16_wide!(1), products16_wide!(@quad "0x55", "64", "80", "96", "112"))
    };
    (3) => {
        concat!(products16_wide!(2), products16_wide!(@quad "0xaa", "128", "144", "160", "176"))
    };
    (4) => {
        concat!(products16_wide!(3), products16_wide!(@quad "0xff", "192", "208", "224", "240"))
    };
}

/// [`products16`] for a panel of 8 outputs in two registers `{s0}`, `{s1}` (a quad's spread
/// made once per register, as `pmaddubsw` overwrites it; two quads side by side in `{t0}`..
/// `{t3}`): 32 instructions a group where a 16-wide panel of an 8-output layer would spend
/// 64 on half zero weights.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! products8 {
    (1) => {
        products!(("t0", "0x00", "0", "s0"), ("t1", "0x00", "16", "s1"))
    };
    (2) => {
        products!(
            ("t0", "0x00", "0", "s0"),
            ("t1", "0x00", "16", "s1"),
            ("t2", "0x55", "32", "s0"),
            ("t3", "0x55", "48", "s1"),
        )
    };
    (3) => {
        concat!(
            products8!(2),
            products!(("t0", "0xaa", "64", "s0"), ("t1", "0xaa", "80", "s1"))
        )
    };
    (4) => {
        concat!(
            products8!(2),
            products!(
                ("t0", "0xaa", "64", "s0"),
                ("t1", "0xaa", "80", "s1"),
                ("t2", "0xff", "96", "s0"),
                ("t3", "0xff", "112", "s1"),
            )
        )
    };
}

/// [`products16`] for a panel of 4 outputs in one register `{s0}`, the group's four quads
/// side by side in `{t0}`..`{t3}`: 16 instructions a group, where an 8-wide panel of a
/// 4-output layer (the cameras' first layers in the narrow CNN) spends 32, half on zero
/// weights.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! products4 {
    (1) => {
        products!(("t0", "0x00", "0", "s0"))
    };
    (2) => {
        products!(("t0", "0x00", "0", "s0"), ("t1", "0x55", "16", "s0"))
    };
    (3) => {
        products!(
            ("t0", "0x00", "0", "s0"),
            ("t1", "0x55", "16", "s0"),
            ("t2", "0xaa", "32", "s0"),
        )
    };
    (4) => {
        products!(
            ("t0", "0x00", "0", "s0"),
            ("t1", "0x55", "16", "s0"),
            ("t2", "0xaa", "32", "s0"),
            ("t3", "0xff", "48", "s0"),
        )
    };
}

/// One row of `$groups` groups into the sums of a panel (`products16` into four registers,
/// `products8` into two, `products4` into one), the whole row in assembly (legacy SSE
/// encoding, for the Atoms): the groups before the last in a loop, per group one unaligned
/// load, with `skip` a test that skips sixteen zero inputs (six instructions that pay only
/// where such groups are common: after ReLU and max-pooling, not in a camera's pixels), then
/// the products; the last group after the loop, without the test and with only its first
/// `$tail` quads (1 to 4): the row's inputs are padded to whole groups with zero weights, so
/// the quads past the inputs add nothing (a 5x5 window of one channel, 25 bytes, spends 3 of
/// the last group's 4). Why assembly: on the V5's eight registers the compiler interleaved a
/// group's quads and spilled sums to the stack (about 40 % more instructions a group), and
/// around per-quad `asm!` blocks it set its loop up again after every group it computed
/// (about a dozen instructions a group); here the loop costs four.
///
/// Inside the caller's `unsafe` block, whose contract gives: `$groups >= 1`, `$groups * 16`
/// bytes at `$bytes`, `$groups * N` aligned vectors at `$vectors`. Reads only those, writes
/// only the named registers and the flags; no stack.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! row_asm {
    (skip, $($rest:tt)*) => {
        row_asm!(@row concat!(
            "pxor {t0}, {t0}\n",
            "pcmpeqb {t0}, {xs}\n",
            "pmovmskb {mask:e}, {t0}\n",
            "cmp {mask:e}, 0xffff\n",
            "je 3f\n",
        ), $($rest)*, mask = out(reg) _,)
    };
    (compute, $($rest:tt)*) => {
        row_asm!(@row "", $($rest)*,)
    };
    (@row $test:expr, $products:ident, $tail:tt, $step:literal, $bytes:expr, $vectors:expr,
        $groups:expr, $ones:expr, [$($s:ident),+], [$($t:ident),+], $($extra:tt)*) => {
        core::arch::asm!(
            "test {n}, {n}",
            "jz 4f",
            "2:",
            "movdqu {xs}, xmmword ptr [{x}]",
            $test,
            $products!(4),
            "3:",
            "add {x}, 16",
            concat!("add {w}, ", $step),
            "dec {n}",
            "jnz 2b",
            "4:",
            "movdqu {xs}, xmmword ptr [{x}]",
            $products!($tail),
            x = inout(reg) $bytes => _,
            w = inout(reg) $vectors => _,
            n = inout(reg) $groups - 1 => _,
            xs = out(xmm_reg) _,
            $($t = out(xmm_reg) _,)+
            ones = in(xmm_reg) $ones,
            $($s = inout(xmm_reg) $s,)+
            $($extra)*
            options(readonly, nostack),
        )
    };
}

/// Each sum register into the running maxima at `$largest` (aligned, one vector per register).
/// `sse2` (the V5's Atom has no SSE4.1 and so no `pmaxsd`): per register a copy, `pcmpgtd`
/// against the maximum in memory, `pand`, `pandn` from memory, `por`, the store: six
/// instructions, where the compiler, keeping four maxima and four sums in the V5's eight
/// registers, moved them through the stack (about 45 instructions a row of a 16-wide panel,
/// callgrind). `sse41` (the V6): `pmaxsd` from memory and the store, two. The sum registers
/// are left holding the maxima.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
macro_rules! merge_largest {
    (@register sse2, $s:literal, $offset:literal) => {
        concat!(
            "movdqa {t}, {", $s, "}\n",
            "pcmpgtd {t}, xmmword ptr [{m} + ", $offset, "]\n",
            "pand {", $s, "}, {t}\n",
            "pandn {t}, xmmword ptr [{m} + ", $offset, "]\n",
            "por {", $s, "}, {t}\n",
            "movdqa xmmword ptr [{m} + ", $offset, "], {", $s, "}\n",
        )
    };
    (@register sse41, $s:literal, $offset:literal) => {
        concat!(
            "pmaxsd {", $s, "}, xmmword ptr [{m} + ", $offset, "]\n",
            "movdqa xmmword ptr [{m} + ", $offset, "], {", $s, "}\n",
        )
    };
    // The block: the maxima's address, SSE2's temporary, the sum registers.
    (@asm sse2, $text:expr, $largest:expr, $($sums:tt)*) => {
        core::arch::asm!($text, m = in(reg) $largest, t = out(xmm_reg) _, $($sums)* options(nostack, preserves_flags))
    };
    (@asm sse41, $text:expr, $largest:expr, $($sums:tt)*) => {
        core::arch::asm!($text, m = in(reg) $largest, $($sums)* options(nostack, preserves_flags))
    };
    ($set:ident, $largest:expr, [$s0:ident]) => {
        merge_largest!(@asm $set, merge_largest!(@register $set, "s0", "0"), $largest,
            s0 = inout(xmm_reg) $s0 => _,)
    };
    ($set:ident, $largest:expr, [$s0:ident, $s1:ident]) => {
        merge_largest!(@asm $set, concat!(
            merge_largest!(@register $set, "s0", "0"),
            merge_largest!(@register $set, "s1", "16"),
        ), $largest, s0 = inout(xmm_reg) $s0 => _, s1 = inout(xmm_reg) $s1 => _,)
    };
    ($set:ident, $largest:expr, [$s0:ident, $s1:ident, $s2:ident, $s3:ident]) => {
        merge_largest!(@asm $set, concat!(
            merge_largest!(@register $set, "s0", "0"),
            merge_largest!(@register $set, "s1", "16"),
            merge_largest!(@register $set, "s2", "32"),
            merge_largest!(@register $set, "s3", "48"),
        ), $largest, s0 = inout(xmm_reg) $s0 => _, s1 = inout(xmm_reg) $s1 => _,
            s2 = inout(xmm_reg) $s2 => _, s3 = inout(xmm_reg) $s3 => _,)
    };
}

/// One SSSE3 kernel: `unsafe fn $name::<TAIL, SSE41>(x, weights, acc, zeros)`, panels of
/// `$width` outputs in the sum registers `[$s..]` (`$width / 4` of them), each row's groups by
/// `$products` (`$step` bytes of weights a group) in [`row_asm`], the last group's first
/// `TAIL` quads only (`TAIL` must be [`QuadPanels::tail_quads`]), the row's sums merged into
/// the running maxima ([`merge_largest`]: with `pmaxsd` where `SSE41`), the cells, panels and
/// rows walked by [`ssse3_panels`]; the zero-group test as `zeros` says. The three widths
/// differ only in these arguments; [`u8s8_max_product_ssse3`] picks the function for a layout.
/// (The macro is defined on every target, so that its uses resolve; the functions it writes
/// are x86's.)
macro_rules! ssse3_kernel {
    ($(#[$doc:meta])* $name:ident, $products:ident, $step:literal, $width:literal, $registers:literal,
        [$($s:ident),+], [$($t:ident),+]) => {
        $(#[$doc])*
        ///
        /// # Safety
        #[doc = concat!("The CPU must have SSSE3, and SSE4.1 where `SSE41`; `weights.width()` must be ", stringify!($width), ".")]
        #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
        #[target_feature(enable = "ssse3")]
        pub(crate) unsafe fn $name<const TAIL: usize, const SSE41: bool>(
            x: &[u8],
            weights: &QuadPanels,
            acc: &mut [i32],
            zeros: ZeroGroups,
        ) {
            assert_eq!(TAIL, weights.tail_quads(), "the last group's quads");
            let ones = _mm_set1_epi16(1);
            // SAFETY (both rows): `ssse3_panels` hands over one whole row of `groups >= 1`
            // groups, the panel's `groups` groups of `$width` aligned vectors and
            // `$registers` aligned maxima; it checks the layout; the quads past `TAIL` in the
            // last group have zero weights (checked above); the caller's contract gives SSSE3
            // and, where `SSE41`, SSE4.1.
            match zeros {
                ZeroGroups::Skip => {
                    let row = ssse3_row!(skip, $products, $step, ones, [$($s),+], [$($t),+]);
                    unsafe { ssse3_panels::<$width, $registers>(x, weights, acc, row) }
                }
                ZeroGroups::Compute => {
                    let row = ssse3_row!(compute, $products, $step, ones, [$($s),+], [$($t),+]);
                    unsafe { ssse3_panels::<$width, $registers>(x, weights, acc, row) }
                }
            }
        }
    };
}

/// The row closure of an [`ssse3_kernel`]: zeroed sums, the row's groups in [`row_asm`]
/// (`$zeros`: `skip` or `compute`; the last group's first `TAIL` quads), the sums merged into
/// the maxima at `largest` (`SSE41`: with `pmaxsd`). `TAIL` and `SSE41` are the kernel's
/// constants, so each kernel keeps one arm of each choice.
macro_rules! ssse3_row {
    ($zeros:ident, $products:ident, $step:literal, $ones:ident, [$($s:ident),+], [$($t:ident),+]) => {
        |inputs: *const u8, vectors: *const __m128i, groups: usize, largest: *mut __m128i| unsafe {
            $(let mut $s = _mm_setzero_si128();)+
            match TAIL {
                1 => row_asm!($zeros, $products, 1, $step, inputs, vectors, groups, $ones, [$($s),+], [$($t),+]),
                2 => row_asm!($zeros, $products, 2, $step, inputs, vectors, groups, $ones, [$($s),+], [$($t),+]),
                3 => row_asm!($zeros, $products, 3, $step, inputs, vectors, groups, $ones, [$($s),+], [$($t),+]),
                _ => row_asm!($zeros, $products, 4, $step, inputs, vectors, groups, $ones, [$($s),+], [$($t),+]),
            }
            if SSE41 {
                merge_largest!(sse41, largest, [$($s),+]);
            } else {
                merge_largest!(sse2, largest, [$($s),+]);
            }
        }
    };
}

/// The SSSE3 kernel for `weights`' layout (panels of 4, 8 or 16) and its last group's quads
/// ([`QuadPanels::tail_quads`]), merging with `pmaxsd` where `sse41`.
///
/// # Safety
/// The CPU must have SSSE3, and SSE4.1 where `sse41`.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
pub(crate) unsafe fn u8s8_max_product_ssse3(
    x: &[u8],
    weights: &QuadPanels,
    acc: &mut [i32],
    zeros: ZeroGroups,
    sse41: bool,
) {
    macro_rules! tails {
        ($kernel:ident, $sse41:literal) => {
            // SAFETY: the caller's contract; each kernel checks its width and tail.
            match weights.tail_quads() {
                1 => unsafe { $kernel::<1, $sse41>(x, weights, acc, zeros) },
                2 => unsafe { $kernel::<2, $sse41>(x, weights, acc, zeros) },
                3 => unsafe { $kernel::<3, $sse41>(x, weights, acc, zeros) },
                _ => unsafe { $kernel::<4, $sse41>(x, weights, acc, zeros) },
            }
        };
    }
    match (weights.width, sse41) {
        (4, false) => tails!(u8s8_max_product_4c_ssse3, false),
        (4, true) => tails!(u8s8_max_product_4c_ssse3, true),
        (8, false) => tails!(u8s8_max_product_8c_ssse3, false),
        (8, true) => tails!(u8s8_max_product_8c_ssse3, true),
        (_, false) => tails!(u8s8_max_product_16c_ssse3, false),
        (_, true) => tails!(u8s8_max_product_16c_ssse3, true),
    }
}

#[cfg(target_arch = "x86")]
ssse3_kernel!(
    /// The 32-bit build (the V5) of the 16-wide kernel, which x86-64's build documents: two
    /// products side by side ([`products16`]), as the V5's eight vector registers allow.
    u8s8_max_product_16c_ssse3, products16, "256", 16, 4, [s0, s1, s2, s3], [t0, t1]
);

#[cfg(target_arch = "x86_64")]
ssse3_kernel!(
    /// [`u8s8_max_product_scalar`] with SSSE3 (`pmaddubsw`, `pmaddwd`) on 128-bit vectors, panels of
    /// 16 outputs held in four registers. The inputs are read a group (sixteen bytes) at a
    /// time: one load, with [`ZeroGroups::Skip`] one test that skips sixteen zero inputs, and
    /// `pshufd` to spread each quad over the lanes and `movdqa` to copy it for the quad's
    /// other products (`pmaddubsw` overwrites its operand); the weights are `pmaddubsw`'s
    /// aligned memory operand. That is four instructions per sixteen outputs of a quad, with
    /// the sums, the input, the ones and four products side
    /// by side ([`products16_wide`]; the 32-bit build for the V5, in its eight registers, two:
    /// [`products16`]). Each row's sums then go into the running maxima in memory
    /// ([`merge_largest`]). The row loop is in assembly ([`row_asm`]; callgrind, int8 CNN
    /// forward: V5 6.46 M -> 5.57 M, V6 4.86 M -> 4.64 M).
    u8s8_max_product_16c_ssse3, products16_wide, "256", 16, 4, [s0, s1, s2, s3], [t0, t1, t2, t3]
);

ssse3_kernel!(
    /// [`u8s8_max_product_16c_ssse3`] for layers of at most 8 outputs: one panel of 8 in two registers
    /// ([`products8`]).
    u8s8_max_product_8c_ssse3, products8, "128", 8, 2, [s0, s1], [t0, t1, t2, t3]
);

ssse3_kernel!(
    /// [`u8s8_max_product_16c_ssse3`] for layers of at most 4 outputs: one panel of 4 in one register
    /// ([`products4`]).
    u8s8_max_product_4c_ssse3, products4, "64", 4, 1, [s0], [t0, t1, t2, t3]
);

/// The cell, panel and row loops of the SSSE3 kernels: for each cell of `acc` and each panel
/// of `N` outputs (`R = N / 4` registers), `row_sums(inputs, vectors, groups, largest)` sums
/// one row of the cell's inputs against the panel's weights (its loop in assembly) and
/// merges the sums into the `R` running maxima at `largest` (aligned). The layout and the
/// sizes are checked once per call, and the loops walk pointers: with slices and iterators
/// the compiler worked out each cell's chunks again, a division included (about 75
/// instructions a cell of the V5's 8-wide kernel, callgrind).
///
/// # Safety
/// `row_sums` may read `groups * GROUP` bytes at `inputs`, `groups * N` aligned vectors at
/// `vectors` and `R` aligned vectors at `largest`, and write the latter, and no more; this
/// function checks the layout (`N` wide, aligned, whole groups) and hands it only such rows,
/// panels and maxima.
#[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
#[inline(always)]
unsafe fn ssse3_panels<const N: usize, const R: usize>(
    x: &[u8],
    weights: &QuadPanels,
    acc: &mut [i32],
    row_sums: impl Fn(*const u8, *const __m128i, usize, *mut __m128i),
) {
    assert!(weights.width == N && R * 4 == N && !weights.pairs);
    let (cells, rows) = weights.cells_in(x, acc);
    let row = weights.padded_inputs();
    let groups = row / GROUP;
    assert!(groups > 0);
    let outputs = weights.outputs;
    let panels = outputs.div_ceil(N);
    // A panel: `groups` groups of `N` vectors of 16 bytes; whole panels, the first aligned
    // (so every one is: a panel is a multiple of 128 bytes).
    let panel_len = groups * GROUP * N;
    let values = weights.values();
    assert!(
        values.len() == panels * panel_len
            && values.as_ptr().cast::<WeightBlock>().is_aligned()
            && panel_len.is_multiple_of(16)
    );
    for cell in 0..cells {
        // SAFETY: `cells_in` checked that `x` holds `cells * rows` rows of `row` bytes.
        let cell_x = unsafe { x.as_ptr().add(cell * rows * row) };
        let cell_acc = &mut acc[cell * outputs..(cell + 1) * outputs];
        for panel in 0..panels {
            // SAFETY: panel `panel` of the `panels` checked above.
            let vectors = unsafe { values.as_ptr().add(panel * panel_len).cast::<__m128i>() };
            // SAFETY: SSE2 is part of every x86 target this crate builds for (i686, x86-64).
            let mut largest = [unsafe { _mm_set1_epi32(i32::MIN) }; R];
            for r in 0..rows {
                // SAFETY: row `r` of the cell, the panel, the maxima: `row_sums`' contract.
                unsafe { row_sums(cell_x.add(r * row), vectors, groups, largest.as_mut_ptr()) };
            }
            let out = &mut cell_acc[panel * N..((panel + 1) * N).min(outputs)];
            write_sums::<N>(out, |target| {
                // SAFETY: `R` stores of four lanes into the `N` `i32` at `target`.
                unsafe {
                    for (k, most) in largest.iter().enumerate() {
                        _mm_storeu_si128(target.cast::<__m128i>().add(k), *most);
                    }
                }
            });
        }
    }
}
