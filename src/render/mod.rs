//! Differentiable emission-absorption volume renderer: forward and analytic backward.
//! (Being written: issue 4.)
