//! `vemlight cameras nats://HOST:PORT`: the cameras publishing on a broker, from the statuses
//! they send once a second (docs/RENDER.md, "Through a NATS broker"), as a table or JSON.

use crate::publish::cameras::{self, BrokerUrl};
use crate::publish::login::LoginArgs;
use anyhow::{Context, bail};
use std::io::Write;

#[derive(clap::Args)]
pub struct CamerasArgs {
    /// The broker, nats://HOST:PORT (credentials from the environment or the flags below).
    pub url: String,
    /// Print the cameras' statuses as a JSON array instead of a table.
    #[arg(long)]
    pub json: bool,
    /// How long to listen for statuses, seconds (each camera sends one a second).
    #[arg(long, default_value_t = cameras::LISTEN.as_secs_f64(), value_name = "S")]
    pub listen: f64,
    #[command(flatten)]
    pub login: LoginArgs,
}

/// Lists the cameras on stdout.
pub fn run(args: &CamerasArgs) -> anyhow::Result<()> {
    let url = BrokerUrl::parse(&args.url).map_err(anyhow::Error::msg)?;
    if url.camera.is_some() || url.lights.is_some() {
        bail!("'{}': give the broker alone, {}", args.url, url.server);
    }
    if !(args.listen.is_finite() && (0.1..=60.0).contains(&args.listen)) {
        bail!("--listen must be between 0.1 and 60 seconds");
    }
    let listen = std::time::Duration::from_secs_f64(args.listen);
    let auth = args.login.auth()?;
    let found = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the runtime")?
        .block_on(async {
            let client = cameras::connect_now(&url.server, &auth).await?;
            cameras::list(&client, listen).await
        })?;
    let mut out = std::io::stdout().lock();
    if args.json {
        writeln!(out, "{}", serde_json::to_string_pretty(&found)?)?;
    } else if found.is_empty() {
        eprintln!(
            "no camera publishes on {}: no status within {:.1} s",
            url.server, args.listen
        );
    } else {
        write!(out, "{}", cameras::table(&found))?;
    }
    Ok(())
}
