//! Config errors name the field and the problem.

use mars_policy::config::{ConfigError, PolicyConfig};

const SHIPPED: &str = include_str!("../../configs/policy.toml");

fn err_of(edit: impl Fn(&str) -> String) -> String {
    PolicyConfig::from_toml(&edit(SHIPPED)).expect_err("edited config must be refused").to_string()
}

#[test]
fn shipped_config_is_valid_and_matches_table_s1() {
    let cfg = PolicyConfig::from_toml(SHIPPED).unwrap();
    assert_eq!((cfg.model.chunk_len, cfg.model.history_len, cfg.model.k_max), (8, 8, 10));
    assert_eq!((cfg.train.knn_m, cfg.train.batch_size), (20, 32));
    assert_eq!((cfg.train.lambda_rec, cfg.train.lambda_div), (1.0, 1.0));
}

#[test]
fn bad_values_are_named() {
    assert!(err_of(|s| s.replace("history_len = 8", "history_len = 4")).contains("model.history_len"));
    assert!(err_of(|s| s.replace("dit_heads = 4", "dit_heads = 3")).contains("model.dit_heads"));
    assert!(err_of(|s| s.replace("k_max = 10", "k_max = 0")).contains("model.k_max"));
    assert!(err_of(|s| s.replace("noise_a2a_w = 0.1", "noise_a2a_w = 1.5")).contains("model.noise_a2a_w"));
    assert!(err_of(|s| s.replace("lr = 3e-4", "lr = -1.0")).contains("train.lr"));
    assert!(err_of(|s| s.replace("batch_size = 32", "batch_size = 1")).contains("train.batch_size"));
    // The FM ablations' knobs are refused on MARS (the shipped kind), and bad values on FM.
    assert!(err_of(|s| s.replace("k_max = 10", "k_max = 10\nsource_std = 2.0")).contains("model.source_std"));
    assert!(err_of(|s| s.replace("seed = 0", "seed = 0\nfm_lambda_rec = 1.0")).contains("train.fm_lambda_rec"));
    let fm = |s: &str| s.replace("kind = \"mars\"", "kind = \"fm\"");
    assert!(err_of(|s| fm(s).replace("k_max = 10", "k_max = 10\nsource_std = -1.0")).contains("model.source_std"));
    assert!(err_of(|s| fm(s).replace("seed = 0", "seed = 0\nfm_lambda_rec = -1.0")).contains("train.fm_lambda_rec"));
    let ok = fm(SHIPPED)
        .replace("k_max = 10", "k_max = 10\nsource_std = 0.0")
        .replace("seed = 0", "seed = 0\nfm_lambda_rec = 1.0");
    PolicyConfig::from_toml(&ok).expect("the FM ablations are valid on fm");
}

#[test]
fn unknown_fields_wrong_types_and_unknown_kinds_are_parse_errors() {
    assert!(err_of(|s| s.replace("k_max = 10", "k_max = 10\nkmax = 3")).contains("kmax"));
    assert!(err_of(|s| s.replace("epochs = 50", "epochs = \"fifty\"")).contains("epochs"));
    assert!(err_of(|s| s.replace("kind = \"mars\"", "kind = \"ddpm\"")).contains("ddpm"));
}

#[test]
fn missing_file_is_a_read_error_naming_the_path() {
    let e = PolicyConfig::load(std::path::Path::new("/nonexistent/policy.toml")).unwrap_err();
    assert!(matches!(e, ConfigError::Read { .. }));
    assert!(e.to_string().contains("/nonexistent/policy.toml"));
}
