//! The dashboard's HTTP side on bad input: raw requests over TCP loopback to an in-process
//! `serve` with `[http] listen`; every one answered 4xx, none takes the service down.

use crate::common::{Service, connect_client, dashboard_door, free_port, wait_for_subscriber};
use std::path::Path;
use std::time::Duration;

use armtwin_service::config::{Overrides, ServiceConfig};
use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Every test must end by itself within this time.
const TEST_LIMIT: Duration = Duration::from_secs(120);

/// Sends `request` as is and returns the status code and the body (the connection is closed
/// by the request's `Connection: close`, or by the server after a refusal).
async fn raw(port: u16, request: &[u8]) -> (u16, String) {
    let mut stream = TcpStream::connect(("127.0.0.1", port))
        .await
        .expect("connect");
    // A refused request may be answered before all of it is written: a write error is fine.
    let _ = stream.write_all(request).await;
    let mut response = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut response)).await;
    let text = String::from_utf8_lossy(&response).into_owned();
    let status = text
        .split(' ')
        .nth(1)
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("no status line in {text:?}"));
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, body)| body.to_owned())
        .unwrap_or_default();
    (status, body)
}

async fn get(port: u16, target: &str) -> (u16, String) {
    raw(
        port,
        format!("GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_http_input_is_answered_4xx_and_the_service_goes_on() {
    tokio::time::timeout(TEST_LIMIT, async {
        let http_port = free_port();
        let mut service = Service::start(|endpoint| {
            ServiceConfig::parse(
                &format!("[http]\nlisten = \"127.0.0.1:{http_port}\"\n"),
                "test config",
                Path::new("."),
                &Overrides {
                    listen: vec![endpoint.to_owned()],
                    ..Overrides::default()
                },
            )
            .expect("valid config")
        })
        .await;
        // One tracked robot, so pages and streams of a real robot exist beside the bad ones.
        let (client, mut outputs) = connect_client(&service.endpoint).await;
        wait_for_subscriber(&client, "twin/joints/cell/r1").await;
        let sample = json!({"t": 1.0, "q": [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]});
        client
            .put("twin/joints/cell/r1", sample.to_string())
            .await
            .expect("put");
        outputs
            .receive_until("the twin pose", |received| {
                received.iter().any(|(key, _)| key == "twin/pose/cell/r1")
            })
            .await;
        assert_eq!(outputs.on("twin/pose/cell/r1").len(), 1);
        assert_eq!(get(http_port, "/api/robot?id=cell/r1").await.0, 200);

        let (status, body) = get(http_port, "/robot/no/such/robot").await;
        assert_eq!(status, 404);
        assert!(body.contains("not-found"), "{body}");
        assert_eq!(get(http_port, "/robot/cell/r1").await.0, 200);
        let (status, body) = get(http_port, "/api/robot?id=no/such").await;
        assert_eq!((status, body.contains("not tracked")), (404, true), "{body}");
        assert_eq!(get(http_port, "/api/robot/stream?id=nobody").await.0, 404);
        assert_eq!(get(http_port, "/api/robot/frames?id=nobody").await.0, 404);
        assert_eq!(get(http_port, "/api/robot").await.0, 400, "no id");
        assert_eq!(get(http_port, "/api/fleet?limit=many").await.0, 400);
        assert_eq!(get(http_port, "/api/fleet?offset=-1").await.0, 400);
        assert_eq!(get(http_port, "/api/fleet?sort=colour").await.0, 400);
        let (status, body) = get(http_port, "/api/fleet?filter=a**b").await;
        assert_eq!(status, 400);
        assert!(
            body.contains("not a key expression") && !body.contains(".rs:"),
            "{body}"
        );
        let long_filter = format!("/api/fleet?filter={}", "a/".repeat(1000));
        assert_eq!(get(http_port, &long_filter).await.0, 400);
        assert_eq!(get(http_port, "/robot/%FF%FE").await.0, 400, "not UTF-8");
        assert_eq!(get(http_port, "/assets/../Cargo.toml").await.0, 404);
        assert_eq!(get(http_port, "/assets/nothing.js").await.0, 404);
        assert_eq!(get(http_port, "/nowhere").await.0, 404);
        let post = b"POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 4\r\nConnection: close\r\n\r\nabcd";
        assert_eq!(raw(http_port, post).await.0, 405);
        assert_eq!(
            raw(http_port, b"HELLO WORLD\r\n\r\n").await.0,
            400,
            "not HTTP"
        );
        let huge_header = format!(
            "GET /healthz HTTP/1.1\r\nHost: x\r\nX-Padding: {}\r\n\r\n",
            "p".repeat(1 << 20)
        );
        let (status, _) = raw(http_port, huge_header.as_bytes()).await;
        assert!((400..500).contains(&status), "huge header: {status}");
        let huge_uri = format!("/api/fleet?filter={}", "x".repeat(1 << 20));
        let (status, _) = get(http_port, &huge_uri).await;
        assert!((400..500).contains(&status), "huge URI: {status}");
        // A body declared far larger than it is, on a route that takes none.
        let lying = b"GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999999\r\nConnection: close\r\n\r\nab";
        let (status, _) = raw(http_port, lying).await;
        assert!(status == 200 || (400..500).contains(&status), "{status}");

        // Still serving, and the twin still answers.
        assert_eq!(get(http_port, "/healthz").await, (200, "ok\n".to_owned()));
        let (status, metrics) = get(http_port, "/metrics").await;
        assert_eq!(status, 200);
        assert!(
            metrics.contains("armtwin_poses_total{robot=\"cell/r1\"} 1"),
            "{metrics}"
        );
        assert!(metrics.contains("armtwin_robots_tracked 1"), "{metrics}");
        let (status, fleet) = get(http_port, "/api/fleet?filter=cell/*").await;
        assert_eq!(status, 200);
        let fleet: serde_json::Value = serde_json::from_str(&fleet).expect("fleet JSON");
        assert_eq!(fleet["matched"], 1);
        assert_eq!(fleet["rows"][0]["robot"], "cell/r1");

        client.close().await.expect("close client");
        let report = service.stop().await;
        assert_eq!(report.robots, 1);
    })
    .await
    .expect("the test ends in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_address_in_use_fails_the_start() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let address = taken.local_addr().expect("address");
    let config = ServiceConfig::parse(
        &format!("[http]\nlisten = \"{address}\"\n"),
        "test config",
        Path::new("."),
        &Overrides {
            listen: vec![format!("tcp/127.0.0.1:{}", free_port())],
            ..Overrides::default()
        },
    )
    .expect("valid config");
    let http = dashboard_door(&config);
    let outcome = tokio::time::timeout(
        TEST_LIMIT,
        armtwin_service::service::serve(config, Some(http), None, std::future::pending()),
    )
    .await
    .expect("fails at once");
    let error = outcome.expect_err("the address is taken").to_string();
    assert!(error.contains(&address.to_string()), "{error}");
}

#[test]
fn a_listen_address_that_is_none_is_refused() {
    let error = ServiceConfig::parse(
        "[http]\nlisten = \"localhost\"\n",
        "test config",
        Path::new("."),
        &Overrides::default(),
    )
    .expect_err("not an address")
    .to_string();
    assert!(error.contains("http.listen"), "{error}");
}
