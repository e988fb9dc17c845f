//! The hidden layer `tanh(x W + b)` as one differentiable op, through burn's backend extension.
//!
//! burn 0.22's tanh costs most of a PPO update on the CPU: the Flex backend calls the C library's
//! scalar `tanhf` once per value on one core, and autodiff's backward evaluates tanh again from the
//! saved input before forming `1 - tanh^2` in four more tensor passes. Here the forward is one
//! matmul followed by one vectorised, parallel pass (bias add and tanh in place), and the backward
//! reuses the forward's output `y`: `dz = g (1 - y^2)` and the bias gradient (column sums of `dz`)
//! come out of one pass, then two matmuls give the weight and input gradients.
//!
//! Flex and ndarray run the hand-written kernels on f32 data (ndarray's own tanh goes through f64
//! one value at a time); other float types compose the same maths from burn's primitives.

// burn-ndarray is deprecated upstream; the design keeps it working, so its kernels are here too.
#![allow(deprecated)]

use std::borrow::Cow;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::flex::FlexTensor;
use burn::backend::ndarray::{NdArrayTensor, SharedArray};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    backend_extension, Autodiff, Backend, Dispatch, Flex, NdArray, TensorMetadata,
};
use burn::tensor::{DType, Shape, Tensor, TensorData};
use ndarray::{ArrayView, IxDyn};
use rayon::prelude::*;

/// Rows per parallel task in the element-wise kernels. Fixed (not derived from the thread count)
/// so the bias gradient's partial sums, and hence the result, do not depend on the thread count.
const ROWS_PER_TASK: usize = 64;

/// The fused hidden layer as a backend extension.
#[backend_extension(Flex, NdArray, Autodiff)]
pub trait DenseTanhOps: Backend {
    /// `tanh(x W + b)` for `x` `[n, d_in]`, `w` `[d_in, d_out]`, `b` `[d_out]`.
    fn dense_tanh(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        composed_dense_tanh::<Self>(x, w, b)
    }

    /// Given `y = tanh(z)` `[n, d]` and the upstream gradient `g` `[n, d]`: `dz = g (1 - y^2)`
    /// `[n, d]` and its column sums `[d]` (the bias gradient).
    fn tanh_backward(
        y: FloatTensor<Self>,
        g: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>) {
        composed_tanh_backward::<Self>(y, g)
    }
}

/// `tanh(x W + b)` from burn's primitives (any backend, any float type).
fn composed_dense_tanh<B: Backend>(
    x: FloatTensor<B>,
    w: FloatTensor<B>,
    b: FloatTensor<B>,
) -> FloatTensor<B> {
    let d_out = b.shape()[0];
    let z = B::float_matmul(x, w);
    B::float_tanh(B::float_add(z, B::float_reshape(b, Shape::new([1, d_out]))))
}

/// `g (1 - y^2)` and its column sums from burn's primitives.
fn composed_tanh_backward<B: Backend>(
    y: FloatTensor<B>,
    g: FloatTensor<B>,
) -> (FloatTensor<B>, FloatTensor<B>) {
    let d = y.shape()[1];
    let one_minus_square =
        B::float_add_scalar(B::float_neg(B::float_mul(y.clone(), y)), 1f32.into());
    let dz = B::float_mul(g, one_minus_square);
    let db = B::float_reshape(B::float_sum_dim(dz.clone(), 0), Shape::new([d]));
    (dz, db)
}

impl DenseTanhOps for Flex {
    fn dense_tanh(x: FlexTensor, w: FlexTensor, b: FlexTensor) -> FlexTensor {
        if [&x, &w, &b].iter().any(|t| t.dtype() != DType::F32) {
            return composed_dense_tanh::<Flex>(x, w, b);
        }
        let mut z = writable_flex(Flex::float_matmul(x, w));
        add_bias_tanh_parallel(z.storage_mut::<f32>(), &flex_values(&b));
        z
    }

    fn tanh_backward(y: FlexTensor, g: FlexTensor) -> (FlexTensor, FlexTensor) {
        if y.dtype() != DType::F32 || g.dtype() != DType::F32 {
            return composed_tanh_backward::<Flex>(y, g);
        }
        let y_values = flex_values(&y);
        let mut dz = writable_flex(g);
        let db = tanh_backward_parallel(
            &mut dz.storage_mut::<f32>()[..y_values.len()],
            &y_values,
            y.shape()[1],
        );
        let d = db.len();
        (dz, FlexTensor::from_data(TensorData::new(db, [d])))
    }
}

impl DenseTanhOps for NdArray {
    fn dense_tanh(x: NdArrayTensor, w: NdArrayTensor, b: NdArrayTensor) -> NdArrayTensor {
        match (NdArray::float_matmul(x, w), b) {
            (NdArrayTensor::F32(z), NdArrayTensor::F32(b)) => {
                let mut z = standard_layout(z.into_owned());
                let values = z.as_slice_mut().expect("standard layout is one slice");
                add_bias_tanh_parallel(values, &ndarray_values(b.view()));
                NdArrayTensor::from(z)
            }
            (z, b) => {
                let d_out = b.shape()[0];
                NdArray::float_tanh(NdArray::float_add(
                    z,
                    NdArray::float_reshape(b, Shape::new([1, d_out])),
                ))
            }
        }
    }

    fn tanh_backward(y: NdArrayTensor, g: NdArrayTensor) -> (NdArrayTensor, NdArrayTensor) {
        match (y, g) {
            (NdArrayTensor::F32(y), NdArrayTensor::F32(g)) => {
                let device = Default::default();
                let y_values = ndarray_values(y.view());
                let mut dz = standard_layout(g.into_owned());
                let values = dz.as_slice_mut().expect("standard layout is one slice");
                let db = tanh_backward_parallel(values, &y_values, y.shape()[1]);
                let d = db.len();
                let db = NdArray::float_from_data(TensorData::new(db, [d]), &device);
                (NdArrayTensor::from(dz), db)
            }
            (y, g) => composed_tanh_backward::<NdArray>(y, g),
        }
    }
}

impl<B: Backend + DenseTanhOps, C: CheckpointStrategy> DenseTanhOps for Autodiff<B, C> {
    fn dense_tanh(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        b: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct DenseTanhBackward;

        /// `x` (needed for the weight gradient), `w` (for the input gradient), the output `y`.
        type State<B> = (
            Option<FloatTensor<B>>,
            Option<FloatTensor<B>>,
            FloatTensor<B>,
        );

        impl<B: Backend + DenseTanhOps> Backward<B, 3> for DenseTanhBackward {
            type State = State<B>;

            fn backward(
                self,
                ops: Ops<Self::State, 3>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let (x, w, y) = ops.state;
                let [x_node, w_node, b_node] = ops.parents;
                let g = grads.consume::<B>(&ops.node);
                let (dz, db) = B::tanh_backward(y, g);
                if let (Some(node), Some(x)) = (w_node, x) {
                    let dw = B::float_matmul(B::float_transpose(x), dz.clone());
                    grads.register::<B>(node.id, dw);
                }
                if let Some(node) = b_node {
                    grads.register::<B>(node.id, db);
                }
                if let (Some(node), Some(w)) = (x_node, w) {
                    grads.register::<B>(node.id, B::float_matmul(dz, B::float_transpose(w)));
                }
            }
        }

        let (x_tracked, w_tracked) = (x.is_tracked(), w.is_tracked());
        let nodes = [x.node(), w.node(), b.node()];
        let (x, w, b) = (x.into_primitive(), w.into_primitive(), b.into_primitive());
        match DenseTanhBackward
            .prepare::<C>(nodes)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let y = B::dense_tanh(x.clone(), w.clone(), b);
                let state = (w_tracked.then_some(x), x_tracked.then_some(w), y.clone());
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(B::dense_tanh(x, w, b)),
        }
    }
}

/// `tanh(x W + b)` for `x` `[n, d_in]`, `w` `[d_in, d_out]`, `b` `[d_out]` on any device, with or
/// without autodiff.
pub fn dense_tanh(x: Tensor<2>, w: Tensor<2>, b: Tensor<1>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as DenseTanhOps>::dense_tanh(
        x.into_dispatch(),
        w.into_dispatch(),
        b.into_dispatch(),
    ))
}

/// The values of an f32 Flex tensor in row-major order, borrowed when already laid out so.
fn flex_values(tensor: &FlexTensor) -> Cow<'_, [f32]> {
    let n = tensor.shape().num_elements();
    if tensor.is_contiguous() {
        let start = tensor.layout().start_offset();
        Cow::Borrowed(&tensor.storage::<f32>()[start..start + n])
    } else {
        Cow::Owned(tensor.to_contiguous().storage::<f32>()[..n].to_vec())
    }
}

/// The Flex tensor itself when it owns exactly its contiguous values (then it can be written in
/// place), else a contiguous copy.
fn writable_flex(tensor: FlexTensor) -> FlexTensor {
    let n = tensor.shape().num_elements();
    let in_place = tensor.is_unique()
        && tensor.is_contiguous()
        && tensor.layout().start_offset() == 0
        && tensor.bytes().len() == 4 * n;
    if in_place {
        tensor
    } else {
        let shape = tensor.shape();
        FlexTensor::from_data(TensorData::new(flex_values(&tensor).into_owned(), shape))
    }
}

/// The values of an f32 ndarray view in row-major order.
fn ndarray_values(view: ArrayView<'_, f32, IxDyn>) -> Cow<'_, [f32]> {
    match view.to_slice() {
        Some(values) => Cow::Borrowed(values),
        None => Cow::Owned(view.iter().copied().collect()),
    }
}

/// An ndarray array this code may write: unique and in row-major layout (copied if not).
fn standard_layout(mut array: SharedArray<f32>) -> SharedArray<f32> {
    if !array.is_standard_layout() {
        array = array.as_standard_layout().into_owned().into_shared();
    }
    array
}

/// `values = tanh(values + bias)` row by row (`[n, bias.len()]`), on all threads.
fn add_bias_tanh_parallel(values: &mut [f32], bias: &[f32]) {
    let d = bias.len();
    let n = values.len() / d;
    values[..n * d]
        .par_chunks_mut(ROWS_PER_TASK * d)
        .for_each(|rows| add_bias_tanh(rows, bias));
}

/// `g = g (1 - y^2)` for `[n, d]` values, on all threads; returns the column sums of the new `g`.
fn tanh_backward_parallel(g: &mut [f32], y: &[f32], d: usize) -> Vec<f32> {
    let partial_sums: Vec<Vec<f32>> = g
        .par_chunks_mut(ROWS_PER_TASK * d)
        .zip(y.par_chunks(ROWS_PER_TASK * d))
        .map(|(g_rows, y_rows)| {
            let mut sums = vec![0.0f32; d];
            tanh_backward_rows(g_rows, y_rows, &mut sums);
            sums
        })
        .collect();
    // Summed in task order: the same result on any number of threads.
    let mut db = vec![0.0f32; d];
    for sums in partial_sums {
        db.iter_mut().zip(sums).for_each(|(total, s)| *total += s);
    }
    db
}

/// `rows = tanh(rows + bias)` for whole rows of `bias.len()` values.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512vl", "x86_64+avx2+fma"))]
fn add_bias_tanh(rows: &mut [f32], bias: &[f32]) {
    for row in rows.chunks_exact_mut(bias.len()) {
        for (z, &b) in row.iter_mut().zip(bias) {
            *z = tanh(*z + b);
        }
    }
}

/// `g = g (1 - y^2)` over whole rows; `sums` accumulates the column sums of the new `g`.
#[multiversion::multiversion(targets("x86_64+avx512f+avx512vl", "x86_64+avx2+fma"))]
fn tanh_backward_rows(g: &mut [f32], y: &[f32], sums: &mut [f32]) {
    let d = sums.len();
    for (g_row, y_row) in g.chunks_exact_mut(d).zip(y.chunks_exact(d)) {
        for ((g, &y), sum) in g_row.iter_mut().zip(y_row).zip(sums.iter_mut()) {
            *g *= 1.0 - y * y;
            *sum += *g;
        }
    }
}

/// tanh as a branch-free rational function (Eigen's and XLA's float approximation: a degree-13
/// odd numerator over a degree-6 even denominator on [-7.9, 7.9], where tanh reaches 1 in f32),
/// so loops over it vectorise. Plain multiplies and adds, no FMA: the same bits on every CPU.
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    const CLAMP: f32 = 7.905_311;
    const TINY: f32 = 0.0004;
    const A1: f32 = 4.893_524_6e-3;
    const A3: f32 = 6.372_619_3e-4;
    const A5: f32 = 1.485_722_4e-5;
    const A7: f32 = 5.122_297e-8;
    const A9: f32 = -8.604_672e-11;
    const A11: f32 = 2.000_188e-13;
    const A13: f32 = -2.760_768_5e-16;
    const B0: f32 = 4.893_525e-3;
    const B2: f32 = 2.268_434_6e-3;
    const B4: f32 = 1.185_347_1e-4;
    const B6: f32 = 1.198_258_4e-6;
    let c = x.clamp(-CLAMP, CLAMP);
    let c2 = c * c;
    let p = ((((((A13 * c2 + A11) * c2 + A9) * c2 + A7) * c2 + A5) * c2 + A3) * c2 + A1) * c;
    let q = ((B6 * c2 + B4) * c2 + B2) * c2 + B0;
    // Near 0 tanh(x) = x to f32 precision; the quotient would lose the last bits there.
    if x.abs() < TINY {
        x
    } else {
        p / q
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Backend as CpuBackend;
    use burn::tensor::Distribution;

    #[test]
    fn rational_tanh_is_within_a_few_ulp_of_the_exact_value() {
        // Every 1e-4 over [-10, 10], plus the clamp, tiny values and infinities.
        let mut worst = (0.0f64, 0.0f32);
        for k in -100_000..=100_000 {
            let x = k as f32 * 1e-4;
            let exact = (x as f64).tanh();
            let error = (tanh(x) as f64 - exact).abs();
            // Relative to the value, but at least relative to one f32 ulp of 1e-3.
            let scaled = error / exact.abs().max(1e-3) / f32::EPSILON as f64;
            if scaled > worst.0 {
                worst = (scaled, x);
            }
        }
        assert!(worst.0 < 4.0, "{} ulp at x = {}", worst.0, worst.1);
        assert_eq!(tanh(1e-6), 1e-6);
        assert_eq!(tanh(-3e-5), -3e-5);
        assert_eq!((tanh(f32::INFINITY), tanh(f32::NEG_INFINITY)), (1.0, -1.0));
        assert!(tanh(20.0) <= 1.0 && tanh(20.0) > 1.0 - 1e-6);
    }

    /// The fused op and its gradients against burn's own matmul, add, tanh and autodiff.
    fn compare_with_burn_ops(backend: CpuBackend, n: usize, d_in: usize, d_out: usize) {
        let device = backend.device().autodiff();
        let x0 = Tensor::<2>::random([n, d_in], Distribution::Uniform(-2.0, 2.0), &device);
        let w0 = Tensor::<2>::random([d_in, d_out], Distribution::Uniform(-1.0, 1.0), &device);
        let b0 = Tensor::<1>::random([d_out], Distribution::Uniform(-1.0, 1.0), &device);
        // A weighting that makes every output matter differently to the loss.
        let r = Tensor::<2>::random([n, d_out], Distribution::Uniform(-1.0, 1.0), &device);
        let run = |fused: bool| {
            let (x, w, b) = (
                x0.clone().require_grad(),
                w0.clone().require_grad(),
                b0.clone().require_grad(),
            );
            let y = if fused {
                dense_tanh(x.clone(), w.clone(), b.clone())
            } else {
                burn::tensor::activation::tanh(
                    x.clone().matmul(w.clone()) + b.clone().unsqueeze_dim(0),
                )
            };
            let grads = (y.clone() * r.clone()).sum().backward();
            let host = |t: Tensor<2>| t.try_into_vec_as::<f32>().unwrap();
            (
                host(y),
                host(x.grad(&grads).unwrap()),
                host(w.grad(&grads).unwrap()),
                b.grad(&grads).unwrap().try_into_vec_as::<f32>().unwrap(),
            )
        };
        let (fused, reference) = (run(true), run(false));
        let close = |a: &[f32], b: &[f32], tol: f32, what: &str| {
            assert_eq!(a.len(), b.len());
            for (i, (a, b)) in a.iter().zip(b).enumerate() {
                assert!(
                    (a - b).abs() <= tol * (1.0 + b.abs()),
                    "{what}[{i}]: {a} vs {b}"
                );
            }
        };
        close(&fused.0, &reference.0, 1e-6, "y");
        close(&fused.1, &reference.1, 1e-5, "dx");
        close(&fused.2, &reference.2, 1e-5, "dw");
        close(&fused.3, &reference.3, 1e-5, "db");
    }

    #[test]
    fn fused_layer_matches_burn_ops_on_flex_and_ndarray() {
        // More rows than one parallel task, and a ragged last task.
        compare_with_burn_ops(CpuBackend::Flex, 3 * ROWS_PER_TASK + 5, 7, 33);
        compare_with_burn_ops(CpuBackend::NdArray, 70, 7, 33);
    }

    #[test]
    fn bias_gradient_does_not_depend_on_the_thread_count() {
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let device = CpuBackend::Flex.device();
                let values = |phase: f32| -> Tensor<2> {
                    let v: Vec<f32> = (0..40_000)
                        .map(|k| (k as f32 * 0.37 + phase).sin())
                        .collect();
                    Tensor::from_data(TensorData::new(v, [1000, 40]), &device)
                };
                let (y, g) = (values(0.0), values(1.0));
                let (_, db) = Flex::tanh_backward(
                    y.try_into_primitive::<Flex>().unwrap(),
                    g.try_into_primitive::<Flex>().unwrap(),
                );
                db.into_data().to_vec::<f32>().unwrap()
            })
        };
        let (one, two) = (run(1), run(2));
        assert!(one
            .iter()
            .zip(&two)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}
