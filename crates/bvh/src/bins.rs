//! The per-axis bins of a binned SAH split search, shared by the binary and the 4-wide
//! top-down builders: for each axis and bin the corners of the primitives' boxes and their
//! count, as separate arrays (a bin update touches one entry of each).

use geom::Vec4;

/// Per-axis bins: box corners and count of the primitives in each of `N` bins per axis.
#[derive(Clone)]
pub(crate) struct Bins<const N: usize> {
    pub(crate) min: [[Vec4; N]; 3],
    pub(crate) max: [[Vec4; N]; 3],
    pub(crate) cnt: [[u32; N]; 3],
}

impl<const N: usize> Bins<N> {
    /// Empty bins.
    pub(crate) fn new() -> Self {
        Self {
            min: [[Vec4::splat(f32::INFINITY); N]; 3],
            max: [[Vec4::splat(f32::NEG_INFINITY); N]; 3],
            cnt: [[0; N]; 3],
        }
    }

    /// The union of two bin sets (exact and order-independent: min, max and counts).
    pub(crate) fn merge(mut self, o: &Self) -> Self {
        for a in 0..3 {
            for i in 0..N {
                self.min[a][i] = self.min[a][i].min(o.min[a][i]);
                self.max[a][i] = self.max[a][i].max(o.max[a][i]);
                self.cnt[a][i] += o.cnt[a][i];
            }
        }
        self
    }
}
