//! How both daemons log, the HAL and marsd: one set-up, so their logs read alike side by side.

/// The HAL's log and marsd's: to stderr, coloured only on a terminal (a log file or journald gets plain text),
/// `RUST_LOG` if set. RustDDS (the ros2 backend) logs each discovery step at info and warns on every heartbeat to
/// a peer that advertises only loopback locators (tens a second against Cyclone DDS on `lo`): only its errors by
/// default. From main, before any thread logs.
pub fn init_logging() {
    let default_filter = "info,rustdds=error,ros2_client=error";
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| default_filter.into());
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_ansi(ansi).try_init();
}
