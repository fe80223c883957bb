//! The engine's own settings (the network comes from the checkpoint).

/// How an engine is set up at load time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EngineConfig {
    /// Seed of the engine's noise generator. The engine draws its noise exactly as `MarsPolicy::predict` does
    /// (C·D standard normals from a `StdRng` per call, in chunk order), so the same seed gives the same noise.
    pub seed: u64,
    /// Threads for the matrix products. 1 (the default) runs everything on the calling thread, which the
    /// caller pins; this is the mode that performs no heap allocation. With more, the token matrix products go
    /// through gemm's general, rayon-parallel path, which allocates small bookkeeping buffers inside gemm on
    /// every call (and pays rayon's wake-up latency), so it only pays off for models far wider than nav2d's.
    pub threads: usize,
    /// Full-length calls (K = K_max, zero noise) run at load time to seed the cost estimate and to touch
    /// every buffer once; at least 1.
    pub warmup_calls: usize,
    /// Use only `gemm`'s public API (one matrix-vector product per token) instead of its FMA microkernels on
    /// pre-packed weights. The engine picks this by itself on CPUs without AVX2 + FMA; setting it elsewhere
    /// is for comparisons and tests. Allocation-free as well, and about 2× slower.
    pub portable_kernels: bool,
    /// Fault injection (HIL tests, `marsd`'s `[faults]`): busy-wait this long in every ODE step, as a slower
    /// CPU or a larger model would. The cost estimator measures it like any other work, so the deadline cap
    /// reacts to it exactly as it would to real slowness. Zero in production.
    pub injected_step_delay: std::time::Duration,
}

impl Default for EngineConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            threads: 1,
            warmup_calls: 3,
            portable_kernels: false,
            injected_step_delay: std::time::Duration::ZERO,
        }
    }
}

impl EngineConfig {
    pub fn with_seed(seed: u64) -> Self {
        Self { seed, ..Self::default() }
    }

    pub(crate) fn validate(&self) -> Result<(), String> {
        if self.threads == 0 {
            return Err("threads must be at least 1".into());
        }
        if self.warmup_calls == 0 {
            return Err("warmup_calls must be at least 1: the step budget needs a first cost estimate".into());
        }
        Ok(())
    }
}
