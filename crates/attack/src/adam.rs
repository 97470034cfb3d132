//! Adam (Kingma & Ba 2015) on a host vector, with projection onto [0, 1] after each step. Its
//! whole state is plain data, so a checkpoint restores it exactly.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Adam {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Steps taken.
    pub t: u64,
    /// First and second moments. Not in the serialised form: a checkpoint stores them as binary
    /// arrays beside its metadata ([`super::checkpoint`]).
    #[serde(skip)]
    pub m: Vec<f32>,
    #[serde(skip)]
    pub v: Vec<f32>,
}

impl Adam {
    pub fn new(n: usize, lr: f32) -> Self {
        Adam {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            t: 0,
            m: vec![0.0; n],
            v: vec![0.0; n],
        }
    }

    /// One step on `x` with gradient `g`, then clip `x` to [0, 1]. Non-finite gradient entries
    /// are treated as zero (and counted in the return value).
    pub fn step(&mut self, x: &mut [f32], g: &[f32]) -> usize {
        self.step_within(x, g, 0.0, 1.0)
    }

    /// One step without the projection (for parameters that are not colours, e.g. the coarse
    /// levels of [`super::pyramid`]; the caller projects what they compose to).
    pub(crate) fn step_unclipped(&mut self, x: &mut [f32], g: &[f32]) -> usize {
        self.step_within(x, g, f32::NEG_INFINITY, f32::INFINITY)
    }

    fn step_within(&mut self, x: &mut [f32], g: &[f32], lo: f32, hi: f32) -> usize {
        assert_eq!(x.len(), g.len());
        self.t += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.t as i32);
        let c2 = 1.0 - b2.powi(self.t as i32);
        let mut bad = 0;
        for i in 0..x.len() {
            let gi = if g[i].is_finite() {
                g[i]
            } else {
                bad += 1;
                0.0
            };
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * gi;
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * gi * gi;
            let mh = self.m[i] / c1;
            let vh = self.v[i] / c2;
            x[i] = (x[i] - self.lr * mh / (vh.sqrt() + self.eps)).clamp(lo, hi);
        }
        bad
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_by_lr_against_the_gradient_and_zero_gradient_texels_stay() {
        let mut a = Adam::new(3, 0.1);
        let mut x = vec![0.5, 0.5, 0.5];
        a.step(&mut x, &[1.0, -2.0, 0.0]);
        assert!(
            (x[0] - 0.4).abs() < 1e-6 && (x[1] - 0.6).abs() < 1e-6 && x[2] == 0.5,
            "{x:?}"
        );
        let mut y = vec![0.99];
        let mut b = Adam::new(1, 0.5);
        b.step(&mut y, &[-1.0]);
        assert_eq!(y[0], 1.0, "clipped to [0, 1]");
        assert_eq!(b.step(&mut y, &[f32::NAN]), 1);
        assert!(y[0].is_finite());
    }
}
