//! Global gradient-norm clipping: burn's `GradientClippingConfig::Norm` clips each tensor on its
//! own, PPO scales all gradients together so their joint L2 norm is at most `max_norm`.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::Tensor;

struct SquaredNorm<'a> {
    grads: &'a GradientsParams,
    total: Option<Tensor<1>>,
}

impl ModuleVisitor for SquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(grad) = self.grads.get::<D>(param.id) {
            let squares = grad.powi_scalar(2).sum();
            self.total = Some(match self.total.take() {
                Some(total) => total + squares,
                None => squares,
            });
        }
    }
}

struct Scale<'a> {
    grads: &'a mut GradientsParams,
    factor: f32,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(grad) = self.grads.remove::<D>(param.id) {
            self.grads.register(param.id, grad.mul_scalar(self.factor));
        }
    }
}

/// Scales `grads` of `module` so that their global L2 norm is at most `max_norm`; returns the
/// norm before clipping.
pub fn clip_global_grad_norm<M: Module>(
    module: &M,
    grads: &mut GradientsParams,
    max_norm: f32,
) -> f32 {
    let mut norm = SquaredNorm { grads, total: None };
    module.visit(&mut norm);
    let Some(total) = norm.total else {
        return 0.0;
    };
    let norm = total.sqrt().into_scalar::<f32>();
    if norm > max_norm {
        let mut scale = Scale {
            grads,
            factor: max_norm / (norm + 1e-6),
        };
        module.visit(&mut scale);
    }
    norm
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::LinearConfig;
    use burn::tensor::{Tensor, TensorData};

    #[test]
    fn scales_all_gradients_by_one_factor() {
        let device = crate::Backend::DEFAULT.device().autodiff();
        let linear = LinearConfig::new(2, 1).init(&device);
        let x = Tensor::<2>::from_data(TensorData::new(vec![3.0f32, 4.0], [1, 2]), &device);
        // d(sum(xW + b))/dW = x^T = [3, 4], d/db = 1: global norm sqrt(26).
        let loss = linear.forward(x).sum();
        let mut grads = GradientsParams::from_grads(loss.backward(), &linear);
        let norm = clip_global_grad_norm(&linear, &mut grads, 1.0);
        assert!((norm - 26f32.sqrt()).abs() < 1e-5, "{norm}");
        let w: Vec<f32> = grads
            .get::<2>(linear.weight.id)
            .unwrap()
            .try_into_vec_as()
            .unwrap();
        let b: Vec<f32> = grads
            .get::<1>(linear.bias.as_ref().unwrap().id)
            .unwrap()
            .try_into_vec_as()
            .unwrap();
        let s = 1.0 / (26f32.sqrt() + 1e-6);
        assert!(
            (w[0] - 3.0 * s).abs() < 1e-6
                && (w[1] - 4.0 * s).abs() < 1e-6
                && (b[0] - s).abs() < 1e-6
        );
        let clipped_norm = (w[0] * w[0] + w[1] * w[1] + b[0] * b[0]).sqrt();
        assert!((clipped_norm - 1.0).abs() < 1e-5);
        // Below the limit nothing changes.
        let norm_again = clip_global_grad_norm(&linear, &mut grads, 10.0);
        assert!((norm_again - 1.0).abs() < 1e-5);
    }
}
