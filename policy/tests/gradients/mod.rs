//! The gradient check the policy tests share (not in common.rs, which the engine's tests include too).

/// Every variable in `varmap` got a finite, non-zero gradient in `grads` (candle's fused norms, softmax and
/// pooling would silently stop some); `what` names the case in the failure.
pub fn assert_every_var_has_a_gradient(
    varmap: &candle_nn::VarMap,
    grads: &candle_core::backprop::GradStore,
    what: &str,
) {
    let data = varmap.data().lock().unwrap();
    for (name, var) in data.iter() {
        let g = grads.get(var).unwrap_or_else(|| panic!("{what}: no gradient for {name}"));
        let norm = g.sqr().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(norm > 0.0 && norm.is_finite(), "{what}: gradient of {name} is {norm}");
    }
}
