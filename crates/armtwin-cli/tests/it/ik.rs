//! `armtwin ik` end to end: the JSON answer round-trips through `armtwin fk`, and unreachable
//! poses fail with their reason.

use std::process::{Command, Output};

fn armtwin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_armtwin"))
        .args(args)
        .output()
        .expect("armtwin runs")
}

fn json(output: &Output) -> serde_json::Value {
    assert!(
        output.status.success(),
        "failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("JSON")
}

#[test]
fn every_solution_reproduces_the_pose_through_fk() {
    let q = ["0.3", "-1.2", "1.4", "-1.7", "-1.5", "0.4"];
    let tcp = "--tcp=0,0,0.15,0,0,0.5";
    let mut fk_args = vec!["fk", "--model", "ur5e", tcp];
    fk_args.extend(q);
    let pose = json(&armtwin(&fk_args));
    let [x, y, z] = ["x", "y", "z"].map(|k| pose[k].as_f64().unwrap());
    let [qx, qy, qz, qw] = ["qx", "qy", "qz", "qw"].map(|k| pose[k].as_f64().unwrap());
    let pose_arg = format!("--pose={x:?},{y:?},{z:?},{qx:?},{qy:?},{qz:?},{qw:?}");
    let seed_arg = format!("--seed={}", q.join(","));
    let answer = json(&armtwin(&[
        "ik", "--model", "ur5e", tcp, &pose_arg, &seed_arg,
    ]));
    let solutions = answer["solutions"].as_array().unwrap();
    assert_eq!(solutions.len(), 8);
    assert_eq!(answer["wrist_singular"], false);
    let first: Vec<f64> = solutions[0]["q"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (got, want) in first.iter().zip(q) {
        assert!(
            (got - want.parse::<f64>().unwrap()).abs() < 1e-9,
            "{first:?}"
        );
    }
    for solution in solutions {
        let angles: Vec<String> = solution["q"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| format!("{:?}", v.as_f64().unwrap()))
            .collect();
        let mut args = vec!["fk", "--model", "ur5e", tcp];
        args.extend(angles.iter().map(String::as_str));
        let back = json(&armtwin(&args));
        for (key, want) in [("x", x), ("y", y), ("z", z)] {
            assert!((back[key].as_f64().unwrap() - want).abs() < 1e-9);
        }
        assert!(["left", "right"].contains(&solution["shoulder"].as_str().unwrap()));
    }
}

#[test]
fn an_unreachable_pose_fails_with_its_reason() {
    let output = armtwin(&["ik", "--model", "ur10e", "--pose", "3,0,0,0,0,0,1"]);
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("unreachable"), "{stderr}");
    assert!(!stderr.contains("NaN"), "{stderr}");
    let output = armtwin(&["ik", "--model", "ur10e", "--pose", "0.5,0,0"]);
    assert!(!output.status.success());
    assert!(String::from_utf8_lossy(&output.stderr).contains("7 values"));
}
