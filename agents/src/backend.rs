//! The one place that picks burn's CPU backend.
//!
//! Both backends are compiled in; [`Backend::DEFAULT`] is the one measured faster on this machine
//! (see `rlpkg bench ppo --backend ...`).

use burn::tensor::Device;

/// burn CPU backends the trainer can run on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// burn's pure-Rust `flex` backend.
    Flex,
    /// burn-ndarray (deprecated upstream in favour of flex).
    NdArray,
}

impl Backend {
    /// The backend used for training and evaluation.
    pub const DEFAULT: Backend = Backend::Flex;

    /// The device without autodiff (rollouts, evaluation).
    pub fn device(self) -> Device {
        match self {
            Backend::Flex => Device::flex(),
            #[allow(deprecated)] // kept working on purpose: the design names ndarray
            Backend::NdArray => Device::ndarray(),
        }
    }

    /// Parses `flex` or `ndarray`.
    pub fn parse(name: &str) -> Option<Backend> {
        match name {
            "flex" => Some(Backend::Flex),
            "ndarray" => Some(Backend::NdArray),
            _ => None,
        }
    }

    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Flex => "flex",
            Backend::NdArray => "ndarray",
        }
    }
}
