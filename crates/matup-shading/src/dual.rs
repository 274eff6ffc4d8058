//! Forward-mode dual numbers over the ten [`Svbrdf`] parameters: the analytic Jacobian of a
//! model written once, generically, for `f32` and `Dual`. Hand-written because the only
//! maintained crate (num-dual) brings nalgebra along for what is eighty lines of arithmetic.

use std::ops::{Add, Div, Mul, Neg, Sub};

use matup_core::shading::Svbrdf;

const N: usize = Svbrdf::LEN;

/// A value and its derivatives with respect to the ten texel parameters.
#[derive(Clone, Copy, Debug)]
pub struct Dual {
    pub value: f32,
    pub grad: [f32; N],
}

/// The arithmetic a generic shading model needs.
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    fn constant(v: f32) -> Self;
    fn value(self) -> f32;
    fn sqrt(self) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    /// Clamped to [lo, hi]; outside that range the result is constant (zero gradient).
    fn clamp_to(self, lo: f32, hi: f32) -> Self;
    /// At least `lo` (a floored denominator).
    fn at_least(self, lo: f32) -> Self {
        self.clamp_to(lo, f32::INFINITY)
    }
}

impl Real for f32 {
    fn constant(v: f32) -> Self {
        v
    }
    fn value(self) -> f32 {
        self
    }
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    fn sin(self) -> Self {
        f32::sin(self)
    }
    fn cos(self) -> Self {
        f32::cos(self)
    }
    fn clamp_to(self, lo: f32, hi: f32) -> Self {
        self.clamp(lo, hi)
    }
}

impl Dual {
    /// The `index`-th parameter, with derivative 1 with respect to itself.
    pub fn variable(value: f32, index: usize) -> Self {
        let mut grad = [0.0; N];
        grad[index] = 1.0;
        Dual { value, grad }
    }

    /// `f(value)` with derivative `f'(value)` applied by the chain rule.
    fn chain(self, value: f32, derivative: f32) -> Self {
        Dual {
            value,
            grad: self.grad.map(|g| g * derivative),
        }
    }
}

impl Real for Dual {
    fn constant(value: f32) -> Self {
        Dual {
            value,
            grad: [0.0; N],
        }
    }
    fn value(self) -> f32 {
        self.value
    }
    fn sqrt(self) -> Self {
        let s = self.value.sqrt();
        self.chain(s, 0.5 / s)
    }
    fn sin(self) -> Self {
        self.chain(self.value.sin(), self.value.cos())
    }
    fn cos(self) -> Self {
        self.chain(self.value.cos(), -self.value.sin())
    }
    fn clamp_to(self, lo: f32, hi: f32) -> Self {
        if self.value < lo {
            Dual::constant(lo)
        } else if self.value > hi {
            Dual::constant(hi)
        } else {
            self
        }
    }
}

impl Add for Dual {
    type Output = Dual;
    fn add(self, o: Dual) -> Dual {
        Dual {
            value: self.value + o.value,
            grad: std::array::from_fn(|i| self.grad[i] + o.grad[i]),
        }
    }
}

impl Sub for Dual {
    type Output = Dual;
    fn sub(self, o: Dual) -> Dual {
        Dual {
            value: self.value - o.value,
            grad: std::array::from_fn(|i| self.grad[i] - o.grad[i]),
        }
    }
}

impl Mul for Dual {
    type Output = Dual;
    // The product rule adds, which clippy's heuristic mistakes for a typo.
    #[allow(clippy::suspicious_arithmetic_impl)]
    fn mul(self, o: Dual) -> Dual {
        Dual {
            value: self.value * o.value,
            grad: std::array::from_fn(|i| self.grad[i] * o.value + self.value * o.grad[i]),
        }
    }
}

impl Div for Dual {
    type Output = Dual;
    #[allow(clippy::suspicious_arithmetic_impl)]
    fn div(self, o: Dual) -> Dual {
        let inv = 1.0 / o.value;
        let q = self.value * inv;
        Dual {
            value: q,
            grad: std::array::from_fn(|i| (self.grad[i] - q * o.grad[i]) * inv),
        }
    }
}

impl Neg for Dual {
    type Output = Dual;
    fn neg(self) -> Dual {
        Dual {
            value: -self.value,
            grad: self.grad.map(|g| -g),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_of_a_composite() {
        // f(x, y) = sqrt(x·y) / (x + sin y)
        let (x, y) = (Dual::variable(1.3, 0), Dual::variable(0.7, 1));
        let f = (x * y).sqrt() / (x + y.sin());
        let g = |x: f64, y: f64| (x * y).sqrt() / (x + y.sin());
        let h = 1e-6;
        let dx = (g(1.3 + h, 0.7) - g(1.3 - h, 0.7)) / (2.0 * h);
        let dy = (g(1.3, 0.7 + h) - g(1.3, 0.7 - h)) / (2.0 * h);
        assert!((f.grad[0] as f64 - dx).abs() < 1e-5);
        assert!((f.grad[1] as f64 - dy).abs() < 1e-5);
    }
}
