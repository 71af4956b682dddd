//! `skybake serve` and `skybake healthcheck`.

use skybake_physics::Error;

use crate::error::{CliError, Result};
use crate::flags::ServeArgs;
use crate::io::load_settings;

pub fn serve(args: ServeArgs) -> Result<()> {
    let mut settings = load_settings(args.config.as_deref())?;
    if let Some(bind) = args.bind {
        settings.server.bind = bind;
    }
    if let Some(dir) = args.cache_dir {
        settings.cache.dir = dir;
    }
    if let Some(url) = args.cache_url {
        settings.cache.url = url;
    }
    settings.validate()?;
    skybake_service::server::run(settings).map_err(CliError::Failure)
}

/// `skybake healthcheck`: exit 0 when the service at `addr` (default: the configured bind
/// address) answers `GET /healthz` with 200.
pub fn healthcheck(addr: Option<String>) -> Result<()> {
    let addr = match addr {
        Some(a) => a,
        None => load_settings(None)?.server.bind,
    };
    let addr = addr
        .parse()
        .map_err(|_| Error::invalid("addr", format!("'{addr}' is not HOST:PORT")))?;
    skybake_service::server::healthcheck(addr).map_err(CliError::Failure)
}
