//! What each kind of per-robot Zenoh entity costs to declare as a fleet grows: one peer session
//! declares, for robots `fleet/r00000` …, the entities chosen (the twin's pose, deviation,
//! metrics and events publishers; its two input keys; its liveliness token) while a second peer
//! session, connected to it over TCP loopback, subscribes to the poses and watches the tokens.
//! Every Zenoh declaration matches its key against the keys beside it, so the time per robot
//! grows with the robots already declared; the kinds differ in how much. With `puts`, it then
//! times puts round robin over the robots, through the publishers when they are declared and
//! on the plain keys otherwise: what a declared publisher saves per message. Then, with
//! `undeclare`, it times undeclaring every entity one by one (tokens first), or, with `close`,
//! closing the declaring session with everything still declared; either way until the watcher
//! has seen every token go.
//!
//! `cargo run --release -p armtwin-bench --example declare_cost -- ROBOTS KINDS [PORT]`, KINDS a
//! comma-separated list of `publishers`, `keys`, `tokens`, `puts`, `undeclare`, `close`. Prints
//! the time at every 1 000 robots, then the totals.
#![allow(
    clippy::expect_used,
    reason = "a measuring binary: a Zenoh failure ends the measurement"
)]
#![allow(
    clippy::print_stdout,
    clippy::print_stderr,
    reason = "a measuring tool's report"
)]

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use zenoh::sample::SampleKind;
use zenoh::{Config, Session, Wait};

/// The twin's output streams with a publisher each.
const OUTPUTS: [&str; 4] = ["pose", "deviation", "metrics", "events"];
/// Puts timed with `puts`.
const PUTS: usize = 100_000;
/// How long the watcher may take to see every token.
const TOKENS_LIMIT: Duration = Duration::from_secs(600);

fn session(port: u16, listen: bool) -> Session {
    let mut config = Config::default();
    let endpoint = format!("[\"tcp/127.0.0.1:{port}\"]");
    let (listen_on, connect_to) = if listen {
        (endpoint.as_str(), "[]")
    } else {
        ("[]", endpoint.as_str())
    };
    for (key, value) in [
        ("mode", "\"peer\""),
        ("scouting/multicast/enabled", "false"),
        ("listen/endpoints", listen_on),
        ("connect/endpoints", connect_to),
    ] {
        config.insert_json5(key, value).expect("valid setting");
    }
    zenoh::open(config).wait().expect("session")
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let robots: usize = args
        .get(1)
        .and_then(|n| n.parse().ok())
        .expect("ROBOTS: a count");
    let kinds: Vec<&str> = args.get(2).map_or("", String::as_str).split(',').collect();
    let port: u16 = args.get(3).map_or(17447, |p| p.parse().expect("PORT"));
    let has = |kind: &str| kinds.contains(&kind);

    let declarer = session(port, true);
    let watcher = session(port, false);
    let tokens_seen = Arc::new(AtomicUsize::new(0));
    let tokens_gone = Arc::new(AtomicUsize::new(0));
    let poses_seen = Arc::new(AtomicUsize::new(0));
    let (seen, gone) = (Arc::clone(&tokens_seen), Arc::clone(&tokens_gone));
    let _tokens = watcher
        .liveliness()
        .declare_subscriber("twin/alive/**")
        .callback(move |sample| {
            let counter = if sample.kind() == SampleKind::Delete {
                &gone
            } else {
                &seen
            };
            counter.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .expect("liveliness subscriber");
    let counter = Arc::clone(&poses_seen);
    let _poses = watcher
        .declare_subscriber("twin/pose/**")
        .callback(move |_| {
            counter.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .expect("subscriber");
    std::thread::sleep(Duration::from_secs(1));

    let started = Instant::now();
    let (mut publishers, mut keys, mut tokens) = (Vec::new(), Vec::new(), Vec::new());
    for i in 0..robots {
        let robot = format!("fleet/r{i:05}");
        if has("publishers") {
            for stream in OUTPUTS {
                let key = format!("twin/{stream}/{robot}");
                publishers.push(declarer.declare_publisher(key).wait().expect("publisher"));
            }
        }
        if has("keys") {
            for stream in ["joints", "measured"] {
                let key = format!("twin/{stream}/{robot}");
                keys.push(declarer.declare_keyexpr(key).wait().expect("key"));
            }
        }
        if has("tokens") {
            let key = format!("twin/alive/{robot}");
            tokens.push(
                declarer
                    .liveliness()
                    .declare_token(key)
                    .wait()
                    .expect("token"),
            );
        }
        if (i + 1) % 1000 == 0 {
            eprintln!(
                "{:6} robots declared at {:7.2} s, {} tokens seen",
                i + 1,
                started.elapsed().as_secs_f64(),
                tokens_seen.load(Ordering::Relaxed)
            );
        }
    }
    let declared_s = started.elapsed().as_secs_f64();
    if has("tokens") {
        while tokens_seen.load(Ordering::Relaxed) < robots && started.elapsed() < TOKENS_LIMIT {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    println!(
        "{robots} robots, {}: declared in {declared_s:.2} s, {} tokens seen at {:.2} s",
        kinds.join(","),
        tokens_seen.load(Ordering::Relaxed),
        started.elapsed().as_secs_f64()
    );

    if has("puts") && robots > 0 {
        let payload = vec![0_u8; 200];
        let plain_keys: Vec<String> = (0..robots)
            .map(|i| format!("twin/pose/fleet/r{i:05}"))
            .collect();
        let started = Instant::now();
        for n in 0..PUTS {
            let i = n % robots;
            let put = if publishers.is_empty() {
                declarer.put(&plain_keys[i], payload.clone()).wait()
            } else {
                publishers[i * OUTPUTS.len()].put(payload.clone()).wait()
            };
            put.expect("put");
        }
        let sent_s = started.elapsed().as_secs_f64();
        println!(
            "{PUTS} puts {} in {sent_s:.2} s: {:.0} per second ({} received; puts drop when the link is full)",
            if publishers.is_empty() {
                "on plain keys"
            } else {
                "through publishers"
            },
            PUTS as f64 / sent_s,
            poses_seen.load(Ordering::Relaxed)
        );
    }

    if has("undeclare") || has("close") {
        let started = Instant::now();
        if has("close") {
            declarer.close().wait().expect("close");
            println!(
                "session closed in {:.2} s with {} tokens, {} publishers and {} keys declared",
                started.elapsed().as_secs_f64(),
                tokens.len(),
                publishers.len(),
                keys.len()
            );
        } else {
            let count = tokens.len();
            for token in tokens.drain(..) {
                token.undeclare().wait().expect("undeclare token");
            }
            let tokens_s = started.elapsed().as_secs_f64();
            let publishers_count = publishers.len();
            for publisher in publishers.drain(..) {
                publisher.undeclare().wait().expect("undeclare publisher");
            }
            let publishers_s = started.elapsed().as_secs_f64() - tokens_s;
            let keys_count = keys.len();
            for key in keys.drain(..) {
                declarer.undeclare(key).wait().expect("undeclare key");
            }
            println!(
                "undeclared one by one: {count} tokens in {tokens_s:.2} s, {publishers_count} publishers in {publishers_s:.2} s, {keys_count} keys in {:.2} s",
                started.elapsed().as_secs_f64() - tokens_s - publishers_s
            );
        }
        let expected = tokens_seen.load(Ordering::Relaxed);
        while tokens_gone.load(Ordering::Relaxed) < expected && started.elapsed() < TOKENS_LIMIT {
            std::thread::sleep(Duration::from_millis(10));
        }
        println!(
            "the watcher saw {} of {expected} tokens go within {:.2} s",
            tokens_gone.load(Ordering::Relaxed),
            started.elapsed().as_secs_f64()
        );
    }
}
