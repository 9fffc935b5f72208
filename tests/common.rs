//! The service on real loopback sockets, shared by the test modules: a
//! server task on free ports (HTTP, and gRPC if asked), stopped like
//! SIGTERM stops the binary (a drain) when its sender fires or is dropped.

use std::net::SocketAddr;

use ilqr_service::server::{AppState, Config, run_with_grpc};
use serde_json::{Value, json};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

pub struct Server {
    pub addr: SocketAddr,
    /// The gRPC address, if it serves gRPC.
    pub grpc: Option<SocketAddr>,
    pub stop: Option<oneshot::Sender<()>>,
    pub task: JoinHandle<std::io::Result<()>>,
}

impl Server {
    /// HTTP only.
    pub async fn start(config: Config) -> Self {
        Self::serve(config, false).await
    }

    /// HTTP and gRPC.
    pub async fn with_grpc(config: Config) -> Self {
        Self::serve(config, true).await
    }

    async fn serve(config: Config, grpc: bool) -> Self {
        let http = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let grpc = match grpc {
            true => Some(TcpListener::bind("127.0.0.1:0").await.unwrap()),
            false => None,
        };
        let addr = http.local_addr().unwrap();
        let grpc_addr = grpc.as_ref().map(|l| l.local_addr().unwrap());
        let state = AppState::new(config).unwrap();
        let (stop, stopped) = oneshot::channel();
        let task = tokio::spawn(run_with_grpc(http, grpc, state, async {
            let _ = stopped.await;
        }));
        Self {
            addr,
            grpc: grpc_addr,
            stop: Some(stop),
            task,
        }
    }

    pub async fn default() -> Self {
        Self::start(Config::default()).await
    }

    pub fn url(&self, path: &str) -> String {
        format!("http://{}{path}", self.addr)
    }

    /// POST `body` as JSON to `path`.
    pub async fn post_to(&self, path: &str, body: &Value) -> reqwest::Response {
        reqwest::Client::new()
            .post(self.url(path))
            .json(body)
            .send()
            .await
            .unwrap()
    }

    pub async fn get(&self, path: &str) -> reqwest::Response {
        reqwest::get(self.url(path)).await.unwrap()
    }
}

/// A solve that runs until its time limit: a long horizon, no tolerance,
/// and 100 distant obstacles that make every iteration slow (~0.1 s) without
/// shaping the solution, so it neither converges nor stalls (`no_progress`)
/// within the few seconds these tests allow.
pub fn slow(time_limit_ms: u64) -> Value {
    let obstacles: Vec<Value> = (0..100)
        .map(|j| json!({"center": [1000.0 + f64::from(j), 1000.0], "weight": 1.0}))
        .collect();
    json!({"horizon": 10000, "dt": 0.0005, "obstacles": obstacles,
           "solver": {"tolerance": 0, "max_iterations": 10000, "time_limit_ms": time_limit_ms},
           "output": {"gains": false, "trace": false}})
}
