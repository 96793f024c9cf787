//! The axes' decoupling: a square matrix over `N` axes' positions (µm in,
//! µm out), without memory. The board runs two of them in its control tick
//! (`fpi_firmware::control::task`):
//!
//! * the **input matrix** (sensors → axes): each axis's position is a
//!   combination of every position sensor's reading, which takes out the
//!   sensors' cross-talk (a sensor that reads 0.2 % of the other axis);
//! * the **output matrix** (axes → stacks): each stack's command is a
//!   combination of every axis's command, which takes out the flexure's
//!   parasitic motion (Y moving 1.5 % of X's output). The commands are µm of
//!   each axis's own output, before each stack's inverse model, so the matrix
//!   is the inverse of the stage's static cross gains `(I + C)⁻¹`, where
//!   `C[i][j]` is µm of axis `i` per µm of axis `j`'s own output.
//!
//! A third, the **preload coupling** ([`Preload`]), is the first paper's
//! coupled equation for several stacks: the preload on stack `i` is its FEM
//! table's at its own extension plus `K[i][j]` N per µm of every other stack
//! `j`'s extension. The board adds it to each stack's model force
//! (`ControllerConfig::sense_coupled`), so the other stacks' motion is
//! neither a dynamic force for the damping nor a residual for the force
//! channel's slow part to chase.
//!
//! The matrices are the identity (the coupling zero) until autotune measures the coupling (drive each
//! axis, measure all) and sets them. A matrix far from the identity would
//! change the loops a model's validator checked one axis at a time, so
//! [`Matrix::new`] refuses an entry outside [`DIAGONAL`] on the diagonal or
//! beyond ±[`OFF_DIAGONAL_MAX`] off it: stages couple by a few percent.
//!
//! **Q contract.** Entries are `I2F30` (range [−2, 2), 9.3·10⁻¹⁰ per LSB);
//! positions `I16F16` µm. Each output is the exact 64-bit sum of `N`
//! products (`I18F46`), rounded to nearest once and saturated to ±32 768 µm;
//! `N` multiply-accumulates per axis, no division, no panic.

use fixed::types::I2F30;

use crate::error::ModelError;
use crate::process::SplitProcess;
use crate::q::{Micrometres, Newtons, NewtonsPerUm};

/// The diagonal's accepted range: an axis's own gain may be corrected by
/// −20 % … +25 % (its own loops' gains are the model's).
pub const DIAGONAL: (f64, f64) = (0.8, 1.25);
/// The largest off-diagonal entry, either sign: a coupling of 10 %.
pub const OFF_DIAGONAL_MAX: f64 = 0.1;

/// One entry of a [`Matrix`]: a gain, µm/µm, `I2F30`.
pub type Entry = I2F30;

/// A square matrix over `N` axes (configuration): `y = M·x`, µm in, µm out.
/// Its entries are checked near the identity ([`Matrix::new`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Matrix<const N: usize> {
    rows: [[Entry; N]; N],
    identity: bool,
}

impl<const N: usize> Matrix<N> {
    /// The identity: every axis is its own.
    pub const IDENTITY: Self = {
        let mut rows = [[Entry::ZERO; N]; N];
        let mut i = 0;
        while i < N {
            rows[i][i] = Entry::ONE;
            i += 1;
        }
        Self {
            rows,
            identity: true,
        }
    };

    /// A matrix of `rows` (`rows[i][j]`: the gain of input `j` in output
    /// `i`); refused with the first entry outside its range
    /// ([`ModelError::MatrixEntryOutOfRange`], its row and column).
    pub fn new(rows: [[Entry; N]; N]) -> Result<Self, ModelError> {
        let (lo, hi) = (Entry::from_num(DIAGONAL.0), Entry::from_num(DIAGONAL.1));
        let off = Entry::from_num(OFF_DIAGONAL_MAX);
        for (i, row) in rows.iter().enumerate() {
            for (j, &m) in row.iter().enumerate() {
                let ok = if i == j {
                    (lo..=hi).contains(&m)
                } else {
                    m.abs() <= off
                };
                if !ok {
                    return Err(ModelError::MatrixEntryOutOfRange {
                        row: i as u8,
                        col: j as u8,
                    });
                }
            }
        }
        let identity = rows == Self::IDENTITY.rows;
        Ok(Self { rows, identity })
    }

    /// A matrix of `rows` given as numbers: refused as [`Matrix::new`]
    /// refuses, and a value that is not finite as out of range.
    pub fn from_f64(rows: [[f64; N]; N]) -> Result<Self, ModelError> {
        let mut q = [[Entry::ZERO; N]; N];
        for (i, row) in rows.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                q[i][j] = Entry::checked_from_num(v).ok_or(ModelError::MatrixEntryOutOfRange {
                    row: i as u8,
                    col: j as u8,
                })?;
            }
        }
        Self::new(q)
    }

    /// The matrix that undoes a coupling `c` (`c[i][j]`: how much of input
    /// `j` reaches output `i`, the diagonal unused): `(I + c)⁻¹`, by
    /// Gauss–Jordan elimination with partial pivoting in `f64` (not on the
    /// tick: when a decoupling is made). Refused as [`Matrix::from_f64`]
    /// refuses its result; a coupling with no inverse as an entry out of
    /// range at its pivot.
    pub fn undoing(c: [[f64; N]; N]) -> Result<Self, ModelError> {
        let mut a = [[0.0; N]; N];
        let mut inv = [[0.0; N]; N];
        for i in 0..N {
            for j in 0..N {
                a[i][j] = if i == j { 1.0 } else { c[i][j] };
            }
            inv[i][i] = 1.0;
        }
        for col in 0..N {
            let pivot = (col..N)
                .max_by(|&p, &q| a[p][col].abs().total_cmp(&a[q][col].abs()))
                .unwrap_or(col);
            let singular = ModelError::MatrixEntryOutOfRange {
                row: col as u8,
                col: col as u8,
            };
            let p = a[pivot][col];
            if p.is_nan() || p.abs() <= 1e-12 {
                return Err(singular);
            }
            a.swap(col, pivot);
            inv.swap(col, pivot);
            for j in 0..N {
                a[col][j] /= p;
                inv[col][j] /= p;
            }
            for r in (0..N).filter(|&r| r != col) {
                let f = a[r][col];
                for j in 0..N {
                    a[r][j] -= f * a[col][j];
                    inv[r][j] -= f * inv[col][j];
                }
            }
        }
        Self::from_f64(inv)
    }

    /// The entries, `rows[i][j]`.
    pub const fn rows(&self) -> &[[Entry; N]; N] {
        &self.rows
    }

    /// Whether it is the identity (then the board skips it).
    pub const fn is_identity(&self) -> bool {
        self.identity
    }

    /// Its leading `K × K` block, the matrix of a stage with the first `K`
    /// of its axes; `None` if it couples those axes with another (an entry
    /// outside the block that is not the identity's).
    pub fn leading<const K: usize>(&self) -> Option<Matrix<K>> {
        let mut rows = [[Entry::ZERO; K]; K];
        for (i, row) in self.rows.iter().enumerate() {
            for (j, &m) in row.iter().enumerate() {
                match (rows.get_mut(i).and_then(|r| r.get_mut(j)), i == j) {
                    (Some(e), _) => *e = m,
                    (None, true) if m == Entry::ONE => {}
                    (None, false) if m == Entry::ZERO => {}
                    (None, _) => return None,
                }
            }
        }
        Matrix::new(rows).ok()
    }
}

impl<const N: usize> Default for Matrix<N> {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl<const N: usize> SplitProcess<[Micrometres; N]> for Matrix<N> {
    /// `M·x`, each output rounded to nearest once and saturated.
    #[inline]
    fn process(&self, _: &mut (), x: [Micrometres; N]) -> [Micrometres; N] {
        let y = product(
            &self.rows.map(|r| r.map(Entry::to_bits)),
            x.map(Micrometres::to_bits),
            Entry::FRAC_NBITS,
        );
        y.map(Micrometres::from_bits)
    }
}

/// The largest preload coupling, either sign, N/µm (a stiff flexure's is a
/// few tenths: the XY stage's 0.5).
pub const PRELOAD_MAX: f64 = 4.0;

/// The stacks' preload coupling (configuration): `K[i][j]`, N on stack `i`
/// per µm of stack `j`'s extension, `I16F16`; the diagonal zero (a stack's
/// own preload is its FEM table's).
///
/// **Q contract.** Each stack's coupled preload is the exact 64-bit sum of
/// `N` products (`I32F32`), rounded to nearest once and saturated to the
/// signal range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Preload<const N: usize> {
    rows: [[NewtonsPerUm; N]; N],
    none: bool,
}

impl<const N: usize> Preload<N> {
    /// No coupling: the stacks are independent.
    pub const NONE: Self = Self {
        rows: [[NewtonsPerUm::ZERO; N]; N],
        none: true,
    };

    /// The coupling of `rows` (`rows[i][j]`, N/µm); refused with the first
    /// entry on the diagonal that is not zero, or beyond ±[`PRELOAD_MAX`]
    /// ([`ModelError::PreloadCouplingOutOfRange`]).
    pub fn new(rows: [[NewtonsPerUm; N]; N]) -> Result<Self, ModelError> {
        let max = NewtonsPerUm::from_num(PRELOAD_MAX);
        for (i, row) in rows.iter().enumerate() {
            for (j, &k) in row.iter().enumerate() {
                if (i == j && k != NewtonsPerUm::ZERO) || k.abs() > max {
                    return Err(ModelError::PreloadCouplingOutOfRange {
                        row: i as u8,
                        col: j as u8,
                    });
                }
            }
        }
        let none = rows == Self::NONE.rows;
        Ok(Self { rows, none })
    }

    /// The coupling of `rows` given as numbers (N/µm): refused as
    /// [`Preload::new`] refuses, and a value that is not finite as out of
    /// range.
    pub fn from_f64(rows: [[f64; N]; N]) -> Result<Self, ModelError> {
        let mut q = [[NewtonsPerUm::ZERO; N]; N];
        for (i, row) in rows.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                q[i][j] = NewtonsPerUm::checked_from_num(v).ok_or(
                    ModelError::PreloadCouplingOutOfRange {
                        row: i as u8,
                        col: j as u8,
                    },
                )?;
            }
        }
        Self::new(q)
    }

    /// The entries, `rows[i][j]`, N/µm.
    pub const fn rows(&self) -> &[[NewtonsPerUm; N]; N] {
        &self.rows
    }

    /// Whether every coupling is zero (then the board skips it).
    pub const fn is_none(&self) -> bool {
        self.none
    }

    /// Its leading `K × K` block; `None` if it couples those stacks with
    /// another.
    pub fn leading<const K: usize>(&self) -> Option<Preload<K>> {
        let mut rows = [[NewtonsPerUm::ZERO; K]; K];
        for (i, row) in self.rows.iter().enumerate() {
            for (j, &k) in row.iter().enumerate() {
                match rows.get_mut(i).and_then(|r| r.get_mut(j)) {
                    Some(e) => *e = k,
                    None if k == NewtonsPerUm::ZERO => {}
                    None => return None,
                }
            }
        }
        Preload::new(rows).ok()
    }
}

impl<const N: usize> Default for Preload<N> {
    fn default() -> Self {
        Self::NONE
    }
}

impl<const N: usize> SplitProcess<[Micrometres; N], [Newtons; N]> for Preload<N> {
    /// Each stack's coupled preload from every stack's extension (µm), N.
    #[inline]
    fn process(&self, _: &mut (), x: [Micrometres; N]) -> [Newtons; N] {
        let rows = self.rows.map(|r| r.map(NewtonsPerUm::to_bits));
        let f = product(&rows, x.map(Micrometres::to_bits), NewtonsPerUm::FRAC_NBITS);
        f.map(Newtons::from_bits)
    }
}

/// `rows · x` on raw bits, the entries with `frac` fractional bits: each
/// output the exact 64-bit sum of its products, rounded to nearest once and
/// saturated to `i32` (the one product both [`Matrix`] and [`Preload`] run).
#[inline(always)]
fn product<const N: usize>(rows: &[[i32; N]; N], x: [i32; N], frac: u32) -> [i32; N] {
    rows.map(|row| {
        let mut acc: i64 = 1 << (frac - 1);
        for (m, x) in row.iter().zip(x.iter()) {
            acc += i64::from(*m) * i64::from(*x);
        }
        crate::q::saturate_i32(acc >> frac)
    })
}

/// A part of a [`Decoupling`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Part {
    /// The input matrix (the sensors' cross-talk).
    Input,
    /// The output matrix (the parasitic motion).
    Output,
    /// The preload coupling.
    Preload,
}

/// The board's decoupling (configuration): sensors → axes, axes → stacks,
/// and the stacks' preload coupling.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Decoupling<const N: usize> {
    /// Sensors → axes: takes out the position sensors' cross-talk.
    pub input: Matrix<N>,
    /// Axes → stacks: takes out the flexure's parasitic motion.
    pub output: Matrix<N>,
    /// Each stack's preload from the other stacks' extensions.
    pub preload: Preload<N>,
}

impl<const N: usize> Decoupling<N> {
    /// The matrices the identity, no preload coupling: no decoupling.
    pub const NONE: Self = Self {
        input: Matrix::IDENTITY,
        output: Matrix::IDENTITY,
        preload: Preload::NONE,
    };

    /// The decoupling of a stage whose first `n` axes couple so: each
    /// position sensor reads `crosstalk` of every other axis's output (the
    /// input matrix undoes it), axis `i` moves `parasitic[i][j]` µm per µm of
    /// axis `j`'s own output (the output matrix undoes it: [`Matrix::undoing`]),
    /// and stack `i` feels `preload[i][j]` N per µm of stack `j`'s extension.
    /// Not on the tick (`f64`). Refused with the part the board would not
    /// take and why.
    pub fn of_coupling(
        crosstalk: f64,
        parasitic: [[f64; N]; N],
        preload: [[f64; N]; N],
        n: usize,
    ) -> Result<Self, (Part, ModelError)> {
        let talk = core::array::from_fn(|i| {
            core::array::from_fn(|j| {
                if i != j && i < n && j < n {
                    crosstalk
                } else {
                    0.0
                }
            })
        });
        Ok(Self {
            input: Matrix::undoing(talk).map_err(|e| (Part::Input, e))?,
            output: Matrix::undoing(parasitic).map_err(|e| (Part::Output, e))?,
            preload: Preload::from_f64(preload).map_err(|e| (Part::Preload, e))?,
        })
    }

    /// Every part's leading `K × K` block ([`Matrix::leading`],
    /// [`Preload::leading`]).
    pub fn leading<const K: usize>(&self) -> Option<Decoupling<K>> {
        Some(Decoupling {
            input: self.input.leading()?,
            output: self.output.leading()?,
            preload: self.preload.leading()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn um(v: f64) -> Micrometres {
        Micrometres::from_num(v)
    }

    /// The f64 reference of `M·x`.
    fn reference<const N: usize>(m: &[[f64; N]; N], x: &[f64; N]) -> [f64; N] {
        core::array::from_fn(|i| (0..N).map(|j| m[i][j] * x[j]).sum())
    }

    #[test]
    fn the_identity_passes_every_position_unchanged() {
        let x = [um(-10.0), um(0.0), um(37.123_456)];
        assert_eq!(Matrix::<3>::IDENTITY.process(&mut (), x), x);
        assert!(Matrix::<3>::IDENTITY.is_identity());
        assert!(
            Matrix::<3>::from_f64([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
                .unwrap()
                .is_identity()
        );
    }

    /// The XY stage's inverse cross gains (Y moves 1.5 % of X, X 2 % of Y),
    /// over the stroke: within 2 LSB (31 pm) of the f64 product.
    #[test]
    fn the_product_is_within_two_lsb_of_the_f64_one() {
        let c = [[0.0, 0.02], [0.015, 0.0]];
        let det = 1.0 - c[0][1] * c[1][0];
        let inv = [[1.0 / det, -c[0][1] / det], [-c[1][0] / det, 1.0 / det]];
        let m = Matrix::from_f64(inv).unwrap();
        // The general inverse agrees with the 2 × 2 closed form.
        assert_eq!(Matrix::undoing(c).unwrap(), m);
        assert!(!m.is_identity());
        let mut worst: f64 = 0.0;
        for a in -10..=70 {
            for b in (-10..=70).step_by(7) {
                let x = [a as f64 * 0.51, b as f64 * 0.49];
                let y = m.process(&mut (), x.map(um));
                let r = reference(&inv, &x);
                for k in 0..2 {
                    worst = worst.max((y[k].to_num::<f64>() - r[k]).abs());
                }
            }
        }
        assert!(worst <= 2.0 / 65536.0, "worst {worst} µm");
    }

    /// Applied to what the coupled stage does, the output matrix returns
    /// the commanded positions: `(I + C)·M·r = r`.
    #[test]
    fn the_inverse_of_the_cross_gains_undoes_them() {
        // The XYZ stage's cross gains: `(I + c)·M·r = r`.
        let c = [[0.0, 0.02, 0.005], [0.015, 0.0, 0.005], [0.01, 0.01, 0.0]];
        let m = Matrix::undoing(c).unwrap();
        let r = [30.0, 5.0, 12.0];
        let cmd = m.process(&mut (), r.map(um)).map(|v| v.to_num::<f64>());
        let out: [f64; 3] = core::array::from_fn(|i| {
            cmd[i]
                + (0..3)
                    .filter(|&j| j != i)
                    .map(|j| c[i][j] * cmd[j])
                    .sum::<f64>()
        });
        for k in 0..3 {
            assert!((out[k] - r[k]).abs() < 1e-4, "{out:?}");
        }
        // A coupling that cancels an axis has no inverse: refused.
        let e = Matrix::undoing([[0.0, 1.0], [1.0, 0.0]]).unwrap_err();
        assert!(
            matches!(e, ModelError::MatrixEntryOutOfRange { .. }),
            "{e:?}"
        );
    }

    #[test]
    fn an_entry_beyond_its_range_is_refused_by_its_place() {
        let e = Matrix::from_f64([[1.0, 0.0], [0.2, 1.0]]).unwrap_err();
        assert_eq!(e, ModelError::MatrixEntryOutOfRange { row: 1, col: 0 });
        let e = Matrix::from_f64([[1.0, 0.0], [0.0, 0.5]]).unwrap_err();
        assert_eq!(e, ModelError::MatrixEntryOutOfRange { row: 1, col: 1 });
        let e = Matrix::from_f64([[f64::NAN, 0.0], [0.0, 1.0]]).unwrap_err();
        assert_eq!(e, ModelError::MatrixEntryOutOfRange { row: 0, col: 0 });
        assert!(Matrix::from_f64([[1.25, -0.1], [0.1, 0.8]]).is_ok());
    }

    /// A three-axis matrix serves a two-axis stage where it does not couple
    /// the third axis with the others.
    #[test]
    fn the_leading_block_is_the_matrix_of_fewer_axes() {
        let xy = [[1.0, -0.02, 0.0], [-0.015, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let m = Matrix::<3>::from_f64(xy).unwrap();
        let two = m.leading::<2>().unwrap();
        assert_eq!(
            two,
            Matrix::from_f64([[1.0, -0.02], [-0.015, 1.0]]).unwrap()
        );
        let mut xyz = xy;
        xyz[2][0] = 0.01;
        assert_eq!(Matrix::<3>::from_f64(xyz).unwrap().leading::<2>(), None);
        assert!(Matrix::<3>::IDENTITY.leading::<1>().unwrap().is_identity());
    }

    /// The XY stage's 0.5 N/µm: each stack's coupled preload is the other's
    /// extension times it, within one LSB of the f64 product.
    #[test]
    fn the_preload_coupling_is_each_stacks_load_from_the_others() {
        let k = Preload::from_f64([[0.0, 0.5], [0.5, 0.0]]).unwrap();
        assert!(!k.is_none());
        let f = k.process(&mut (), [um(30.0), um(10.0)]);
        assert!((f[0].to_num::<f64>() - 5.0).abs() < 2.0 / 65536.0, "{f:?}");
        assert!((f[1].to_num::<f64>() - 15.0).abs() < 2.0 / 65536.0, "{f:?}");
        assert!(Preload::<2>::NONE.is_none());
        let e = Preload::from_f64([[0.1, 0.5], [0.5, 0.0]]).unwrap_err();
        assert_eq!(e, ModelError::PreloadCouplingOutOfRange { row: 0, col: 0 });
        let e = Preload::from_f64([[0.0, 0.5], [-4.5, 0.0]]).unwrap_err();
        assert_eq!(e, ModelError::PreloadCouplingOutOfRange { row: 1, col: 0 });
        let three = Preload::<3>::from_f64([[0.0, 0.5, 0.0], [0.5, 0.0, 0.0], [0.0; 3]]).unwrap();
        assert_eq!(three.leading::<2>(), Some(k));
        let xyz = Preload::<3>::from_f64([[0.0, 0.5, 0.2], [0.5, 0.0, 0.0], [0.0; 3]]).unwrap();
        assert_eq!(xyz.leading::<2>(), None);
    }

    /// Saturates at the signal range rather than wrapping.
    #[test]
    fn a_sum_beyond_the_range_saturates() {
        let m = Matrix::from_f64([[1.25, 0.1], [0.1, 1.25]]).unwrap();
        let x = [Micrometres::MAX, Micrometres::MAX];
        assert_eq!(m.process(&mut (), x), [Micrometres::MAX; 2]);
        let x = [Micrometres::MIN, Micrometres::MIN];
        assert_eq!(m.process(&mut (), x), [Micrometres::MIN; 2]);
    }
}
