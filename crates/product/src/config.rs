//! Service settings: `config/default.toml` embedded as the defaults, then a `--config FILE` (TOML,
//! any subset of the same keys), then `SKYBAKE_*` environment variables, then command-line flags.
//! Everything is validated once at start-up; an invalid setting is refused with a message naming it.

use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

/// The embedded defaults.
pub const DEFAULT_TOML: &str = include_str!("../../../config/default.toml");

/// All settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    pub server: ServerSettings,
    pub cache: CacheSettings,
    pub jobs: JobSettings,
    pub defaults: DefaultSettings,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServerSettings {
    pub bind: String,
    pub worker_threads: usize,
    pub compute_threads: usize,
    pub request_timeout_s: f64,
    pub concurrency_limit: usize,
    pub body_limit_bytes: usize,
    /// Longest wait for a request's headers, seconds; on a kept-alive connection the wait for the
    /// next request counts too, so this is also the idle timeout.
    pub header_read_timeout_s: f64,
    /// Most open client connections; more are closed as soon as they are accepted.
    pub max_connections: usize,
    /// Most open connections of one client address; more are closed as soon as they are accepted.
    pub max_connections_per_client: usize,
    /// Longest a request body may take to arrive, seconds (408 after it).
    pub body_read_timeout_s: f64,
    /// Slowest average rate a request body may arrive at after its first
    /// [`BODY_RATE_GRACE_S`] seconds, bytes per second (408 below it); 0 = no minimum.
    pub body_min_rate_bytes_per_s: f64,
    /// Longest a shutdown waits for open connections and computations, seconds.
    pub shutdown_grace_s: f64,
    /// Largest estimated cost of one product request ([`crate::cost`]), cell-wavelength-orders.
    pub max_request_cost: u64,
    /// Largest estimated cost of one frame request or frame plan
    /// ([`crate::frame::FrameCost`]), pixel-voxel-samples.
    pub max_frame_cost: u64,
    /// Largest estimated peak memory of one frame request ([`crate::frame::FrameCost`]), bytes.
    pub max_request_memory_bytes: u64,
    /// Largest estimated cost of one job ([`skybake_job::spec::JobSpec::validate_and_cost`]).
    pub max_job_cost: u64,
    /// Computations waiting for a compute slot before new ones are shed.
    pub max_queued_computations: usize,
    /// Whether a computation nobody waits for any more runs on to fill the cache.
    pub finish_abandoned: bool,
    /// Requests per second per client address on `/v1/*`; 0 = no limit.
    pub rate_limit_per_s: f64,
    /// Requests a client may make at once before the rate applies.
    pub rate_limit_burst: u32,
    /// Comma-separated bearer tokens; empty = no authentication.
    pub api_tokens: String,
    /// Comma-separated paths answered without a token.
    pub auth_exempt: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CacheSettings {
    pub dir: PathBuf,
    /// A bucket shared by several processes (`s3://bucket/prefix`) behind the directory, or
    /// empty for the directory alone.
    pub url: String,
    /// Seconds a lease on a product or a job in the bucket lasts unless its holder renews it.
    pub lease_s: f64,
    pub disk_budget_bytes: u64,
    pub memory_budget_bytes: u64,
    pub response_budget_bytes: u64,
    /// Most bytes of voxel grids and lit cloud volumes kept between frames of the same cloud
    /// ([`crate::frame::FrameReuse`]); 0 = every frame computes everything.
    pub frame_reuse_bytes: u64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobSettings {
    pub workers: usize,
    pub max_products: usize,
    /// Most jobs queued or running at once.
    pub max_live: usize,
    /// Seconds a finished job and its files are kept.
    pub expire_after_s: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DefaultSettings {
    /// Empty = the engine's default set.
    pub wavelengths: String,
    pub quality: String,
}

/// Environment variables read by [`Settings::load`]: (variable, section, key).
pub const ENV_VARS: &[(&str, &str, &str)] = &[
    ("SKYBAKE_BIND", "server", "bind"),
    ("SKYBAKE_WORKER_THREADS", "server", "worker_threads"),
    ("SKYBAKE_COMPUTE_THREADS", "server", "compute_threads"),
    ("SKYBAKE_REQUEST_TIMEOUT_S", "server", "request_timeout_s"),
    ("SKYBAKE_CONCURRENCY_LIMIT", "server", "concurrency_limit"),
    ("SKYBAKE_BODY_LIMIT_BYTES", "server", "body_limit_bytes"),
    (
        "SKYBAKE_HEADER_READ_TIMEOUT_S",
        "server",
        "header_read_timeout_s",
    ),
    ("SKYBAKE_MAX_CONNECTIONS", "server", "max_connections"),
    (
        "SKYBAKE_MAX_CONNECTIONS_PER_CLIENT",
        "server",
        "max_connections_per_client",
    ),
    (
        "SKYBAKE_BODY_READ_TIMEOUT_S",
        "server",
        "body_read_timeout_s",
    ),
    (
        "SKYBAKE_BODY_MIN_RATE_BYTES_PER_S",
        "server",
        "body_min_rate_bytes_per_s",
    ),
    ("SKYBAKE_SHUTDOWN_GRACE_S", "server", "shutdown_grace_s"),
    ("SKYBAKE_MAX_REQUEST_COST", "server", "max_request_cost"),
    ("SKYBAKE_MAX_FRAME_COST", "server", "max_frame_cost"),
    (
        "SKYBAKE_MAX_REQUEST_MEMORY_BYTES",
        "server",
        "max_request_memory_bytes",
    ),
    ("SKYBAKE_MAX_JOB_COST", "server", "max_job_cost"),
    (
        "SKYBAKE_MAX_QUEUED_COMPUTATIONS",
        "server",
        "max_queued_computations",
    ),
    ("SKYBAKE_FINISH_ABANDONED", "server", "finish_abandoned"),
    ("SKYBAKE_RATE_LIMIT_PER_S", "server", "rate_limit_per_s"),
    ("SKYBAKE_RATE_LIMIT_BURST", "server", "rate_limit_burst"),
    ("SKYBAKE_API_TOKENS", "server", "api_tokens"),
    ("SKYBAKE_AUTH_EXEMPT", "server", "auth_exempt"),
    ("SKYBAKE_CACHE_DIR", "cache", "dir"),
    ("SKYBAKE_CACHE_URL", "cache", "url"),
    ("SKYBAKE_LEASE_S", "cache", "lease_s"),
    ("SKYBAKE_DISK_BUDGET_BYTES", "cache", "disk_budget_bytes"),
    (
        "SKYBAKE_MEMORY_BUDGET_BYTES",
        "cache",
        "memory_budget_bytes",
    ),
    (
        "SKYBAKE_RESPONSE_BUDGET_BYTES",
        "cache",
        "response_budget_bytes",
    ),
    ("SKYBAKE_FRAME_REUSE_BYTES", "cache", "frame_reuse_bytes"),
    ("SKYBAKE_JOB_WORKERS", "jobs", "workers"),
    ("SKYBAKE_MAX_JOB_PRODUCTS", "jobs", "max_products"),
    ("SKYBAKE_MAX_LIVE_JOBS", "jobs", "max_live"),
    ("SKYBAKE_JOB_EXPIRE_AFTER_S", "jobs", "expire_after_s"),
    ("SKYBAKE_DEFAULT_WAVELENGTHS", "defaults", "wavelengths"),
    ("SKYBAKE_DEFAULT_QUALITY", "defaults", "quality"),
];

/// `SKYBAKE_*` variables that are not settings and so are not refused at start-up: the log filter,
/// and switches read only by the test suite.
pub const NON_SETTING_ENV_VARS: &[&str] = &[
    "SKYBAKE_LOG",
    "SKYBAKE_EXR_SAMPLE_DIR",
    "SKYBAKE_TEST_S3_ENDPOINT",
];

/// The known setting variables, comma-separated, for error messages.
fn known_env_vars() -> String {
    ENV_VARS
        .iter()
        .map(|(var, _, _)| *var)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The non-empty, trimmed items of a comma-separated list.
fn split_list(s: &str) -> Vec<&str> {
    s.split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .collect()
}

/// Seconds at the start of a request body during which its rate is not checked
/// (`server.body_min_rate_bytes_per_s` applies to the average after them).
pub const BODY_RATE_GRACE_S: f64 = 5.0;

/// Most products a job may hold, whatever the configuration says.
pub const MAX_JOB_PRODUCTS_LIMIT: usize = 1_000_000;

fn config_err(field: &str, reason: impl ToString) -> Error {
    Error::invalid(&format!("config: {field}"), reason)
}

/// Merges `over` into `base` (tables recursively; other values replace).
fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// An environment value typed like the default it replaces.
fn env_value(var: &str, text: &str, like: Option<&toml::Value>) -> Result<toml::Value> {
    Ok(match like {
        Some(toml::Value::Integer(_)) => match text.trim().parse::<i64>() {
            Ok(v) => toml::Value::Integer(v),
            // A float where a whole number is expected is refused by the typed check below.
            Err(_) => toml::Value::Float(
                text.trim()
                    .parse()
                    .map_err(|_| config_err(var, format!("'{text}' is not a whole number")))?,
            ),
        },
        Some(toml::Value::Boolean(_)) => match text.trim() {
            "true" | "1" => toml::Value::Boolean(true),
            "false" | "0" => toml::Value::Boolean(false),
            _ => return Err(config_err(var, format!("'{text}' is not true or false"))),
        },
        Some(toml::Value::Float(_)) => toml::Value::Float(
            text.trim()
                .parse()
                .map_err(|_| config_err(var, format!("'{text}' is not a number")))?,
        ),
        _ => toml::Value::String(text.to_string()),
    })
}

impl Settings {
    /// The embedded defaults alone.
    pub fn defaults() -> Self {
        // The embedded file is checked by a unit test; fall back to parsing errors never happening.
        Self::from_layers(None, &[]).unwrap_or_else(|e| panic!("embedded config/default.toml: {e}"))
    }

    /// Defaults ← `file` ← the process environment's `SKYBAKE_*` variables.
    pub fn load(file: Option<&Path>) -> Result<Self> {
        let text = file
            .map(|p| {
                skybake_store::files::read(p)
                    .map_err(|e| {
                        config_err("--config", format!("cannot read {}: {e}", p.display()))
                    })
                    .and_then(|bytes| {
                        String::from_utf8(bytes).map_err(|e| {
                            config_err("--config", format!("{} is not UTF-8: {e}", p.display()))
                        })
                    })
            })
            .transpose()?;
        // Every SKYBAKE_* variable is taken, so a mistyped one is refused instead of ignored.
        let mut env: Vec<(String, String)> = Vec::new();
        for (name, value) in std::env::vars_os() {
            let Some(name) = name.to_str() else { continue };
            if !name.starts_with("SKYBAKE_") || NON_SETTING_ENV_VARS.contains(&name) {
                continue;
            }
            let value = value
                .into_string()
                .map_err(|_| config_err(name, "not valid UTF-8"))?;
            env.push((name.to_string(), value));
        }
        Self::from_layers(text.as_deref(), &env)
    }

    /// Defaults ← `file_text` (TOML) ← `env` (variable, value) pairs, validated.
    pub fn from_layers(file_text: Option<&str>, env: &[(String, String)]) -> Result<Self> {
        let mut value: toml::Value =
            toml::from_str(DEFAULT_TOML).map_err(|e| config_err("default.toml", e.to_string()))?;
        if let Some(text) = file_text {
            let over: toml::Value =
                toml::from_str(text).map_err(|e| config_err("--config", e.to_string()))?;
            merge(&mut value, over);
        }
        for (var, text) in env {
            let Some((_, section, key)) = ENV_VARS.iter().find(|(v, _, _)| v == var) else {
                return Err(config_err(
                    var,
                    format!(
                        "not a known SKYBAKE_* setting (known: {})",
                        known_env_vars()
                    ),
                ));
            };
            let like = value.get(section).and_then(|s| s.get(key));
            let v = env_value(var, text, like)?;
            if let Some(toml::Value::Table(t)) = value.get_mut(section) {
                t.insert(key.to_string(), v);
            }
        }
        let settings: Settings = value
            .try_into()
            .map_err(|e: toml::de::Error| config_err("settings", e.message()))?;
        settings.validate()?;
        Ok(settings)
    }

    /// Checks every value; errors name the setting.
    pub fn validate(&self) -> Result<()> {
        self.bind_addr()?;
        let s = &self.server;
        if s.worker_threads > 1024 {
            return Err(Error::out_of_range(
                "server.worker_threads",
                s.worker_threads,
                "0 (one per core) to 1024",
            ));
        }
        if s.compute_threads > 1024 {
            return Err(Error::out_of_range(
                "server.compute_threads",
                s.compute_threads,
                "0 (one per core) to 1024",
            ));
        }
        if !(s.request_timeout_s.is_finite()
            && s.request_timeout_s > 0.0
            && s.request_timeout_s <= 86_400.0)
        {
            return Err(Error::out_of_range(
                "server.request_timeout_s",
                s.request_timeout_s,
                "above 0 to 86400 s",
            ));
        }
        if !(1..=1_000_000).contains(&s.concurrency_limit) {
            return Err(Error::out_of_range(
                "server.concurrency_limit",
                s.concurrency_limit,
                "1 to 1000000",
            ));
        }
        if !(1024..=1 << 30).contains(&s.body_limit_bytes) {
            return Err(Error::out_of_range(
                "server.body_limit_bytes",
                s.body_limit_bytes,
                "1024 to 1073741824",
            ));
        }
        for (name, value) in [
            ("server.header_read_timeout_s", s.header_read_timeout_s),
            ("server.body_read_timeout_s", s.body_read_timeout_s),
            ("server.shutdown_grace_s", s.shutdown_grace_s),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= 3600.0) {
                return Err(Error::out_of_range(name, value, "above 0 to 3600 s"));
            }
        }
        if !(1..=1_000_000).contains(&s.max_connections) {
            return Err(Error::out_of_range(
                "server.max_connections",
                s.max_connections,
                "1 to 1000000",
            ));
        }
        if !(1..=s.max_connections).contains(&s.max_connections_per_client) {
            return Err(Error::out_of_range(
                "server.max_connections_per_client",
                s.max_connections_per_client,
                format!("1 to server.max_connections ({})", s.max_connections),
            ));
        }
        if !(s.body_min_rate_bytes_per_s.is_finite()
            && (0.0..=1e9).contains(&s.body_min_rate_bytes_per_s))
        {
            return Err(Error::out_of_range(
                "server.body_min_rate_bytes_per_s",
                s.body_min_rate_bytes_per_s,
                "0 (no minimum) to 1e9",
            ));
        }
        if s.max_request_cost < 1_000_000 {
            return Err(Error::out_of_range(
                "server.max_request_cost",
                s.max_request_cost,
                "at least 1000000",
            ));
        }
        if s.max_frame_cost < 1_000_000 {
            return Err(Error::out_of_range(
                "server.max_frame_cost",
                s.max_frame_cost,
                "at least 1000000",
            ));
        }
        if s.max_request_memory_bytes < 1 << 24 {
            return Err(Error::out_of_range(
                "server.max_request_memory_bytes",
                s.max_request_memory_bytes,
                "at least 16777216",
            ));
        }
        if s.max_job_cost < 1_000_000 {
            return Err(Error::out_of_range(
                "server.max_job_cost",
                s.max_job_cost,
                "at least 1000000",
            ));
        }
        if !(1..=1_000_000).contains(&s.max_queued_computations) {
            return Err(Error::out_of_range(
                "server.max_queued_computations",
                s.max_queued_computations,
                "1 to 1000000",
            ));
        }
        if !(s.rate_limit_per_s.is_finite() && (0.0..=1e6).contains(&s.rate_limit_per_s)) {
            return Err(Error::out_of_range(
                "server.rate_limit_per_s",
                s.rate_limit_per_s,
                "0 (no limit) to 1000000",
            ));
        }
        if !(1..=1_000_000).contains(&s.rate_limit_burst) {
            return Err(Error::out_of_range(
                "server.rate_limit_burst",
                s.rate_limit_burst,
                "1 to 1000000",
            ));
        }
        for t in self.api_tokens() {
            if t.len() < 16 || !t.bytes().all(|b| b.is_ascii_graphic()) {
                return Err(Error::invalid(
                    "server.api_tokens",
                    "each token must be at least 16 printable ASCII characters without spaces",
                ));
            }
        }
        if !(1..=100_000).contains(&self.jobs.max_live) {
            return Err(Error::out_of_range(
                "jobs.max_live",
                self.jobs.max_live,
                "1 to 100000",
            ));
        }
        let e = self.jobs.expire_after_s;
        if !(e.is_finite() && e > 0.0 && e <= 3.2e7) {
            return Err(Error::out_of_range(
                "jobs.expire_after_s",
                e,
                "above 0 to 32000000 s (about a year)",
            ));
        }
        if self.cache.dir.as_os_str().is_empty() {
            return Err(Error::invalid("cache.dir", "must not be empty"));
        }
        let url = self.cache.url.trim();
        if !url.is_empty() && !skybake_store::bucket::is_bucket_url(url) {
            return Err(Error::invalid(
                "cache.url",
                format!("{url}: expected s3://bucket/prefix, or empty for the directory alone"),
            ));
        }
        if !url.is_empty() && !skybake_store::bucket::AVAILABLE {
            return Err(Error::invalid(
                "cache.url",
                format!(
                    "{url}: this skybake was built without the S3 backend; build it with \
                     `cargo build --release --features s3` (the container image has it)"
                ),
            ));
        }
        let l = self.cache.lease_s;
        if !(l.is_finite() && (1.0..=3600.0).contains(&l)) {
            return Err(Error::out_of_range("cache.lease_s", l, "1 to 3600 s"));
        }
        if self.cache.disk_budget_bytes < 1 << 20 {
            return Err(Error::out_of_range(
                "cache.disk_budget_bytes",
                self.cache.disk_budget_bytes,
                "at least 1048576",
            ));
        }
        if !(1..=256).contains(&self.jobs.workers) {
            return Err(Error::out_of_range(
                "jobs.workers",
                self.jobs.workers,
                "1 to 256",
            ));
        }
        if !(1..=MAX_JOB_PRODUCTS_LIMIT).contains(&self.jobs.max_products) {
            return Err(Error::out_of_range(
                "jobs.max_products",
                self.jobs.max_products,
                format!("1 to {MAX_JOB_PRODUCTS_LIMIT}"),
            ));
        }
        if !self.defaults.wavelengths.trim().is_empty() {
            skybake_physics::spectrum::Wavelengths::parse(&self.defaults.wavelengths)
                .map_err(|e| Error::invalid("defaults.wavelengths", e.to_string()))?;
        }
        skybake_physics::atmosphere::quality::Quality::parse(&self.defaults.quality)
            .map_err(|e| Error::invalid("defaults.quality", e.to_string()))?;
        Ok(())
    }

    /// The configured bearer tokens (none: authentication is off).
    pub fn api_tokens(&self) -> Vec<&str> {
        split_list(&self.server.api_tokens)
    }

    /// The paths answered without a token.
    pub fn auth_exempt(&self) -> Vec<&str> {
        split_list(&self.server.auth_exempt)
    }

    /// The parsed bind address.
    pub fn bind_addr(&self) -> Result<SocketAddr> {
        self.server.bind.parse().map_err(|_| {
            Error::invalid(
                "server.bind",
                format!(
                    "'{}' is not an address like 127.0.0.1:8080",
                    self.server.bind
                ),
            )
        })
    }

    /// Engine computations at once (resolved: 0 = cores).
    pub fn compute_threads(&self) -> usize {
        match self.server.compute_threads {
            0 => std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            n => n,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_defaults_are_valid() {
        let s = Settings::from_layers(None, &[]).unwrap();
        assert_eq!(s.server.bind, "127.0.0.1:8080");
        assert_eq!(s.defaults.quality, "standard");
    }

    #[test]
    fn file_then_env_override() {
        let s = Settings::from_layers(
            Some("[server]\nbind = \"0.0.0.0:9000\"\nconcurrency_limit = 7\n"),
            &[
                ("SKYBAKE_CONCURRENCY_LIMIT".into(), "9".into()),
                ("SKYBAKE_CACHE_DIR".into(), "/tmp/x".into()),
                ("SKYBAKE_REQUEST_TIMEOUT_S".into(), "2.5".into()),
                ("SKYBAKE_FRAME_REUSE_BYTES".into(), "0".into()),
            ],
        )
        .unwrap();
        assert_eq!(s.cache.frame_reuse_bytes, 0);
        assert_eq!(
            Settings::from_layers(None, &[])
                .unwrap()
                .cache
                .frame_reuse_bytes,
            384 << 20
        );
        assert_eq!(s.server.bind, "0.0.0.0:9000");
        assert_eq!(s.server.concurrency_limit, 9);
        assert_eq!(s.cache.dir, PathBuf::from("/tmp/x"));
        assert_eq!(s.server.request_timeout_s, 2.5);
    }

    #[test]
    fn invalid_settings_name_themselves() {
        type Case<'a> = (Option<&'a str>, Vec<(String, String)>, &'a str);
        let cases: [Case; 6] = [
            (
                Some("[server]\nbind = \"nowhere\"\n"),
                vec![],
                "server.bind",
            ),
            (Some("[server]\nspeed = 3\n"), vec![], "config: settings"),
            (
                None,
                vec![("SKYBAKE_CONCURRENCY_LIMIT".into(), "lots".into())],
                "config: SKYBAKE_CONCURRENCY_LIMIT",
            ),
            (
                None,
                vec![("SKYBAKE_CONCURRENCY_LIMIT".into(), "0".into())],
                "server.concurrency_limit",
            ),
            (
                None,
                vec![("SKYBAKE_DEFAULT_QUALITY".into(), "ultra".into())],
                "defaults.quality",
            ),
            (Some("[jobs]\nworkers = 0\n"), vec![], "jobs.workers"),
        ];
        for (file, env, field) in cases {
            let e = Settings::from_layers(file, &env).unwrap_err();
            assert_eq!(e.field(), field, "{e}");
        }
    }
}
