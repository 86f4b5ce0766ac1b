//! A real `nats-server` for the tests: on 127.0.0.1 with ports of its own, JetStream in a temp
//! store, a WebSocket listener (for browsers) and the monitoring port, from a config written to a
//! temp dir. scripts/test.sh installs nats-server when it is missing; without it (and without
//! `VEMLIGHT_REQUIRE_BROKER=1`, which scripts/test.sh sets) the broker tests say so and skip.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The `nats-server` binary, if installed (Debian puts it in /usr/sbin).
pub fn nats_server() -> Option<PathBuf> {
    let candidates = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .unwrap_or_default()
        .into_iter()
        .chain([
            "/usr/sbin".into(),
            "/usr/local/bin".into(),
            "/usr/bin".into(),
        ]);
    candidates
        .map(|d| d.join("nats-server"))
        .find(|p| p.is_file())
}

/// Whether nats-server is there; false (after saying why) when it is missing and the run does not
/// require it.
pub fn have_broker(test: &str) -> bool {
    if nats_server().is_none() {
        assert!(
            std::env::var_os("VEMLIGHT_REQUIRE_BROKER").is_none(),
            "nats-server is not installed (scripts/test.sh installs it)"
        );
        eprintln!("skipping {test}: nats-server is not installed (scripts/test.sh installs it)");
        return false;
    }
    true
}

/// A broker with the default settings, or `None` as [`have_broker`] says.
pub fn broker_or_skip(test: &str) -> Option<Broker> {
    have_broker(test).then(|| Broker::start(Settings::default()))
}

/// Knobs of the broker's config.
#[derive(Clone, Debug)]
pub struct Settings {
    /// How long the server waits on a client's socket before cutting it off as a slow consumer.
    pub write_deadline: &'static str,
    /// Bytes pending for one client before it is a slow consumer (at least `max_payload`).
    pub max_pending: u64,
    /// Largest message.
    pub max_payload: u64,
    pub jetstream: bool,
    /// More config at the top level (users and their permissions, say).
    pub extra: String,
    /// More lines inside the `websocket {}` block (`allowed_origins`, say).
    pub websocket: String,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            write_deadline: "2s",
            max_pending: 64 * 1024 * 1024,
            max_payload: 1024 * 1024,
            jetstream: true,
            extra: String::new(),
            websocket: String::new(),
        }
    }
}

/// A running nats-server, killed when dropped.
pub struct Broker {
    child: Option<Child>,
    pub port: u16,
    pub ws_port: u16,
    pub http_port: u16,
    dir: PathBuf,
    /// What the next [`restart`](Broker::restart) writes into the config.
    pub settings: Settings,
}

/// A port free now on 127.0.0.1.
pub fn free_port() -> u16 {
    free_ports::<1>()[0]
}

/// `N` distinct ports free now on 127.0.0.1: all held open until each is chosen, since a port
/// just let go can be handed out again at once (two of one broker's listeners once got the same).
pub fn free_ports<const N: usize>() -> [u16; N] {
    let held: Vec<std::net::TcpListener> = (0..N)
        .map(|_| std::net::TcpListener::bind("127.0.0.1:0").unwrap())
        .collect();
    std::array::from_fn(|i| held[i].local_addr().unwrap().port())
}

impl Broker {
    pub fn start(settings: Settings) -> Broker {
        let dir = std::env::temp_dir().join(format!(
            "vemlight-nats-{}-{}",
            std::process::id(),
            free_port()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let [port, ws_port, http_port] = free_ports();
        let mut b = Broker {
            child: None,
            port,
            ws_port,
            http_port,
            dir,
            settings,
        };
        // Another process may take a port between choosing it and the server binding it: then
        // the server exits at once, and it starts again on new ports.
        for _ in 0..3 {
            if b.try_spawn().is_ok() {
                return b;
            }
            [b.port, b.ws_port, b.http_port] = free_ports();
        }
        b.spawn();
        b
    }

    fn spawn(&mut self) {
        if let Err(log) = self.try_spawn() {
            panic!("nats-server did not come up: {log}");
        }
    }

    /// Starts the server and waits for its ports; the server's log if it exits or is not up in
    /// 15 s.
    fn try_spawn(&mut self) -> Result<(), String> {
        let conf = self.dir.join("nats.conf");
        let store = self.dir.join("js");
        let jetstream = if self.settings.jetstream {
            format!(
                "jetstream {{\n  store_dir: \"{}\"\n  max_memory_store: 268435456\n  max_file_store: 67108864\n}}\n",
                store.display()
            )
        } else {
            String::new()
        };
        let text = format!(
            "server_name: \"{name}\"\nlisten: 127.0.0.1:{port}\nhttp: 127.0.0.1:{http}\nwrite_deadline: \"{wd}\"\nmax_pending: {mp}\nmax_payload: {pl}\n\
             max_connections: 20000\n{jetstream}{extra}\n\
             websocket {{\n  listen: \"127.0.0.1:{ws}\"\n  no_tls: true\n{ws_extra}\n}}\n",
            name = self.name(),
            port = self.port,
            http = self.http_port,
            ws = self.ws_port,
            wd = self.settings.write_deadline,
            mp = self.settings.max_pending,
            pl = self.settings.max_payload,
            extra = self.settings.extra,
            ws_extra = self.settings.websocket,
        );
        std::fs::File::create(&conf)
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
        let child = Command::new(nats_server().expect("nats-server"))
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(self.dir.join("nats.log")).unwrap())
            .spawn()
            .expect("start nats-server");
        self.child = Some(child);
        // Ready once the client and monitoring ports answer.
        let deadline = Instant::now() + Duration::from_secs(15);
        loop {
            let up = [self.port, self.ws_port, self.http_port].iter().all(|p| {
                std::net::TcpStream::connect_timeout(
                    &([127, 0, 0, 1], *p).into(),
                    Duration::from_millis(200),
                )
                .is_ok()
            });
            // Ports chosen free can be taken by another test's broker before this one binds
            // them: then that one answers while this one has exited. Up means this server, by
            // its name, on its monitoring port.
            if up && self.answers_as_itself() {
                return Ok(());
            }
            let exited = self
                .child
                .as_mut()
                .is_some_and(|c| c.try_wait().ok().flatten().is_some());
            if exited || Instant::now() >= deadline {
                self.kill();
                return Err(std::fs::read_to_string(self.dir.join("nats.log")).unwrap_or_default());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The name this server is given in its configuration (unique to the process and ports).
    fn name(&self) -> String {
        format!("vemlight-test-{}-{}", std::process::id(), self.port)
    }

    /// Whether the server on the monitoring port is this one (its `server_name`), alive.
    fn answers_as_itself(&mut self) -> bool {
        let alive = self
            .child
            .as_mut()
            .is_some_and(|c| matches!(c.try_wait(), Ok(None)));
        let name = self
            .try_monitor("varz", Some(Duration::from_secs(2)))
            .ok()
            .and_then(|v| v["server_name"].as_str().map(str::to_owned));
        alive && name.as_deref() == Some(self.name().as_str())
    }

    /// `nats://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("nats://127.0.0.1:{}", self.port)
    }

    /// The WebSocket listener, `ws://127.0.0.1:PORT`.
    pub fn ws_url(&self) -> String {
        format!("ws://127.0.0.1:{}", self.ws_port)
    }

    /// The monitoring endpoint `path` (`varz`, `connz`, `subsz`) as JSON.
    pub fn monitor(&self, path: &str) -> serde_json::Value {
        self.try_monitor(path, None)
            .unwrap_or_else(|e| panic!("monitor /{path}: {e}"))
    }

    /// [`Self::monitor`], or why not: the port does not answer (within `timeout`, if given), or
    /// not with JSON.
    fn try_monitor(
        &self,
        path: &str,
        timeout: Option<Duration>,
    ) -> Result<serde_json::Value, String> {
        use std::io::Read;
        let mut s = std::net::TcpStream::connect(("127.0.0.1", self.http_port))
            .map_err(|e| e.to_string())?;
        s.set_read_timeout(timeout).map_err(|e| e.to_string())?;
        write!(
            s,
            "GET /{path} HTTP/1.0\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
        )
        .map_err(|e| e.to_string())?;
        let mut body = String::new();
        s.read_to_string(&mut body).map_err(|e| e.to_string())?;
        let json = body.split_once("\r\n\r\n").map(|x| x.1).unwrap_or("");
        serde_json::from_str(json).map_err(|e| format!("{e}: {body}"))
    }

    /// Kills the server (a broker that goes away).
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Starts it again on the same ports (a broker restarted: its memory store is empty).
    pub fn restart(&mut self) {
        self.kill();
        self.spawn();
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        self.kill();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}
