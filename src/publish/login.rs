//! Logging in to the broker, for the publishing daemon and for viewers alike: the ways a login
//! can be given ([`NatsAuth`]), the flags and environment that name one ([`LoginArgs`]: never the
//! command line alone, where every user of the machine can read it), and the client options that
//! carry it.

use anyhow::{Context, bail};
use std::path::PathBuf;

/// How a client logs in to the broker; never from the command line alone (docs/API.md).
#[derive(Clone, Default)]
pub enum NatsAuth {
    #[default]
    None,
    Token(String),
    UserPassword(String, String),
    /// A NATS `.creds` file (a user JWT and its NKey seed).
    CredsFile(PathBuf),
}

impl std::fmt::Debug for NatsAuth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            NatsAuth::None => "none",
            NatsAuth::Token(_) => "token",
            NatsAuth::UserPassword(..) => "user and password",
            NatsAuth::CredsFile(_) => "credentials file",
        })
    }
}

/// How a subscriber logs in to the broker, as `serve --publish` does: a credentials file, a token
/// (from a file or `VEMLIGHT_NATS_TOKEN`), or `VEMLIGHT_NATS_USER` and `VEMLIGHT_NATS_PASSWORD`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct LoginArgs {
    /// A NATS credentials file (.creds: user JWT and NKey seed) for the broker.
    #[arg(long, env = "VEMLIGHT_NATS_CREDS", value_name = "FILE")]
    pub nats_creds: Option<PathBuf>,
    /// A file holding the broker's token (or VEMLIGHT_NATS_TOKEN).
    #[arg(long, env = "VEMLIGHT_NATS_TOKEN_FILE", value_name = "FILE")]
    pub nats_token_file: Option<PathBuf>,
}

impl LoginArgs {
    /// The login these flags and the environment name; one way at most.
    pub fn auth(&self) -> anyhow::Result<NatsAuth> {
        let env = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
        let token_file = match &self.nats_token_file {
            Some(path) => Some(
                std::fs::read_to_string(path)
                    .with_context(|| format!("--nats-token-file '{}'", path.display()))?
                    .trim()
                    .to_string(),
            ),
            None => None,
        };
        Ok(
            match (
                &self.nats_creds,
                token_file.or_else(|| env("VEMLIGHT_NATS_TOKEN")),
                env("VEMLIGHT_NATS_USER"),
            ) {
                (Some(path), None, None) => NatsAuth::CredsFile(path.clone()),
                (None, Some(token), None) => {
                    if token.is_empty() {
                        bail!("the NATS token file is empty");
                    }
                    NatsAuth::Token(token)
                }
                (None, None, Some(user)) => {
                    let Some(password) = env("VEMLIGHT_NATS_PASSWORD") else {
                        bail!("VEMLIGHT_NATS_USER is set without VEMLIGHT_NATS_PASSWORD");
                    };
                    NatsAuth::UserPassword(user, password)
                }
                (None, None, None) => NatsAuth::None,
                _ => bail!(
                    "give one way to log in to the broker: --nats-creds, a token (--nats-token-file \
                     or VEMLIGHT_NATS_TOKEN), or VEMLIGHT_NATS_USER and VEMLIGHT_NATS_PASSWORD"
                ),
            },
        )
    }
}

/// Client options carrying `auth` (reading a credentials file).
pub async fn connect_options(auth: &NatsAuth) -> anyhow::Result<async_nats::ConnectOptions> {
    Ok(match auth {
        NatsAuth::None => async_nats::ConnectOptions::new(),
        NatsAuth::Token(t) => async_nats::ConnectOptions::with_token(t.clone()),
        NatsAuth::UserPassword(u, p) => {
            async_nats::ConnectOptions::with_user_and_password(u.clone(), p.clone())
        }
        NatsAuth::CredsFile(path) => async_nats::ConnectOptions::with_credentials_file(path)
            .await
            .with_context(|| format!("--nats-creds '{}'", path.display()))?,
    })
}
