//! ROS 2 sources without a running service: `rmw_zenoh` attachments read in both forms, namespace
//! rules, the configurations refused at load time, the ROS 2 guide's recipes (docs/ros2.md), and
//! the type hashes in keys.

use crate::ros2_fixtures::{
    JOINT_TYPE, NAMESPACE_SOURCES, OUTPUT_CONFIG, POSE_TYPE, attachment, data, keyed_attachment,
    parse,
};

use armtwin_mesh::ros2::{self, Attachment, AttachmentError, KeyScheme, NamespaceRule};
use armtwin_service::config::SourceRobot;
use serde_json::Value;

#[test]
fn attachments_read_in_both_forms_and_every_damage_is_named() {
    for gid in [&[9_u8; 16][..], &[8_u8; 24][..]] {
        for bytes in [
            attachment(42, 1_700_000_000_123_456_789, gid),
            keyed_attachment(42, 1_700_000_000_123_456_789, gid),
        ] {
            let parsed = Attachment::parse(&bytes).expect("an rmw_zenoh attachment");
            assert_eq!(parsed.sequence_number, 42);
            assert_eq!(parsed.source_timestamp_ns, 1_700_000_000_123_456_789);
            assert_eq!(parsed.gid(), gid);
            assert_eq!(
                parsed.source_timestamp_s(),
                Some(1_700_000_000.0 + 123_456_789.0 * 1e-9)
            );
        }
    }
    let good = attachment(7, 1, &[1; 16]);
    assert_eq!(good.len(), 33);
    assert_eq!(
        good,
        ros2::encode_attachment(7, 1, &[1; 16]),
        "armtwin writes what zenoh-ext writes"
    );
    for cut in 0..good.len() {
        let error = Attachment::parse(&good[..cut]).unwrap_err();
        assert!(
            matches!(error, AttachmentError::Truncated { .. }),
            "cut at {cut}: {error}"
        );
    }
    let mut trailing = good.clone();
    trailing.push(0);
    assert_eq!(
        Attachment::parse(&trailing),
        Err(AttachmentError::Trailing { extra: 1 })
    );
    assert_eq!(
        Attachment::parse(&attachment(7, 1, &[1; 25])),
        Err(AttachmentError::GidLength { length: 25 })
    );
    assert_eq!(
        Attachment::parse(&attachment(-1, 1, &[1; 16])),
        Err(AttachmentError::NegativeSequence {
            sequence_number: -1
        })
    );
    // A gid length of 2^63: refused before anything of that size is looked at.
    let mut huge = good[..16].to_vec();
    huge.extend_from_slice(&[0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x7f]);
    assert!(matches!(
        Attachment::parse(&huge),
        Err(AttachmentError::GidLength { .. })
    ));
    let mut overlong = good[..16].to_vec();
    overlong.extend_from_slice(&[0xff; 11]);
    assert!(matches!(
        Attachment::parse(&overlong),
        Err(AttachmentError::Length { .. })
    ));
    let mut wrong_key = keyed_attachment(7, 1, &[1; 16]);
    let at = wrong_key.windows(6).position(|w| w == b"source").unwrap();
    wrong_key[at] = b'S';
    assert!(matches!(
        Attachment::parse(&wrong_key),
        Err(AttachmentError::Key {
            expected: "source_timestamp",
            ..
        })
    ));
    assert!(matches!(
        Attachment::parse(&[0; 300]),
        Err(AttachmentError::TooLarge { bytes: 300 })
    ));
    assert_eq!(
        Attachment::parse(&attachment(7, 0, &[]))
            .unwrap()
            .source_timestamp_s(),
        None
    );
}

#[test]
fn namespace_rules_read_robots_of_both_layouts() {
    let rmw = NamespaceRule::new(KeyScheme::RmwZenoh, "/joint_states", JOINT_TYPE).unwrap();
    let hash = ros2::JOINT_STATE_TYPE_HASH;
    for (key, robot) in [
        (format!("0/ur/joint_states/{JOINT_TYPE}/{hash}"), Some("ur")),
        (
            format!("12/a/b/c/joint_states/{JOINT_TYPE}/TypeHashNotSupported"),
            Some("a/b/c"),
        ),
        (format!("0/joint_states/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/my_joint_states/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/joint_states/extra/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/joint_states/{POSE_TYPE}/{hash}"), None),
        (format!("x/ur/joint_states/{JOINT_TYPE}/{hash}"), None),
        (format!("0/ur/joint_states/{JOINT_TYPE}"), None),
        ("ur/joint_states".to_owned(), None),
    ] {
        assert_eq!(rmw.robot_of(&key), robot, "{key}");
    }
    let bridge =
        NamespaceRule::new(KeyScheme::Bridge, "tcp_pose_broadcaster/pose", POSE_TYPE).unwrap();
    for (key, robot) in [
        ("ur/tcp_pose_broadcaster/pose", Some("ur")),
        ("site/bot1/tcp_pose_broadcaster/pose", Some("site/bot1")),
        ("tcp_pose_broadcaster/pose", None),
        ("ur/pose", None),
        ("ur/x_tcp_pose_broadcaster/pose", None),
    ] {
        assert_eq!(bridge.robot_of(key), robot, "{key}");
    }
}

#[test]
fn sources_that_cannot_work_are_refused_at_load_time() {
    let source = |fields: &str| format!("[[sources]]\n{fields}\n");
    let ros2_joints = "key = \"0/**/joint_states/**\"\ncodec = \"ros2\"\nstream = \"joints\"\n";
    let cases = [
        (
            source("key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\""),
            "sources[0]: needs robot = \"<id>\"",
        ),
        (
            source(&format!("{ros2_joints}robot = \"r\"")),
            "sources[0].scheme: codec = \"ros2\" needs scheme",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\"\nrobot_from_key = \"ros2_namespace\""
            )),
            "robot and robot_from_key exclude each other",
        ),
        (
            source(
                "key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"\ntf_prefix = \"x_\"",
            ),
            "sources[0].tf_prefix: is read only with codec = \"ros2\"",
        ),
        (
            source(
                "key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\"\nrobot_from_key = \"ros2_namespace\"",
            ),
            "sources[0].robot_from_key: is read only with codec = \"ros2\"",
        ),
        (
            source("key = \"twin/**\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\""),
            "intersects armtwin's own 'twin/pose/**'",
        ),
        (
            source(
                "key = \"a/**\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"\n[[sources]]\nkey = \"a/b\"\ncodec = \"json\"\nstream = \"measured\"\nrobot = \"r\"",
            ),
            "sources[1].key: 'a/b' intersects sources[0].key 'a/**'",
        ),
        (
            source(
                "key = \"a/b/c\"\ncodec = \"ros2\"\nstream = \"joints\"\nscheme = \"bridge\"\nrobot_from_key = \"ros2_namespace\"",
            ),
            "never carries topic '/joint_states' under a namespace in the bridge layout",
        ),
        (
            source(
                "key = \"joint_states\"\ncodec = \"ros2\"\nstream = \"joints\"\nscheme = \"bridge\"\nrobot_from_key = \"ros2_namespace\"",
            ),
            "never carries topic '/joint_states'",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot_from_key = \"ros2_namespace\"\ntopic = \"joint-states\""
            )),
            "sources[0].topic: 'joint-states' is not a ROS name",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\"\ntopic = \"/joint_states\""
            )),
            "sources[0].topic: is read only with robot_from_key",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"a/*\""
            )),
            "'a/*' is not a robot id",
        ),
        (
            format!(
                "[service]\nreject_unknown = true\n{}",
                source(&format!(
                    "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\""
                ))
            ),
            "robot 'r' is not configured and service.reject_unknown is true",
        ),
        (
            format!(
                "[robots.r]\nmodel = \"../../config/examples/franka-panda.toml\"\n{}",
                source(&format!(
                    "{ros2_joints}scheme = \"rmw_zenoh\"\nrobot = \"r\""
                ))
            ),
            "6 joint names for robot 'r', whose arm has 7 joints",
        ),
        (
            source(
                "key = \"0/**/tcp_pose_broadcaster/pose/**\"\ncodec = \"ros2\"\nstream = \"measured\"\nscheme = \"bridge\"\nrobot = \"r\"\njoint_names = [\"a\"]",
            ),
            "sources[0].joint_names: is read only with stream = \"joints\"",
        ),
        (
            source(
                "key = \"0/**/tcp_pose_broadcaster/pose/**\"\ncodec = \"ros2\"\nstream = \"measured\"\nscheme = \"bridge\"\nrobot = \"r\"\neffort = \"current_a\"",
            ),
            "sources[0].effort: is read only with stream = \"joints\"",
        ),
        (
            source("key = \"a/b\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"\neffort = \"torque_nm\""),
            "sources[0].effort: is read only with codec = \"ros2\"",
        ),
        (
            source(&format!(
                "{ros2_joints}scheme = \"bridge\"\nrobot = \"r\"\neffort = \"amperes\""
            )),
            "unknown variant `amperes`, expected `current_a` or `torque_nm`",
        ),
        (
            source("key = \"a/b\"\ncodec = \"ros3\"\nstream = \"joints\"\nrobot = \"r\""),
            "unknown variant `ros3`",
        ),
        (
            format!(
                "[robots.default.ros2_pose]\nscheme = \"rmw_zenoh\"\n{}",
                source("key = \"0/**\"\ncodec = \"json\"\nstream = \"joints\"\nrobot = \"r\"")
            ),
            "intersects the twin pose output '0/**/armtwin/tcp_pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3",
        ),
        (
            "[robots.r]\n[[robots.r.sensors]]\nkey_expr = \"0/x\"\n[robots.default.ros2_pose]\nscheme = \"bridge\"\ntopic = \"x\"\n"
                .to_owned(),
            "robots.\"r\".sensors[0].key_expr: '0/x' intersects the twin pose output '**/x'",
        ),
        (
            "[robots.default.ros2_pose]\ntf_prefix = \"a_\"\n".to_owned(),
            "robots.\"default\".ros2_pose.scheme: is needed",
        ),
        (
            "[robots.default.ros2_pose]\nscheme = \"bridge\"\nnamespace = \"ur\"\n".to_owned(),
            "robots.default.ros2_pose.namespace: would give every robot the same key",
        ),
        (
            "[robots.r.ros2_pose]\nscheme = \"bridge\"\nnamespace = \"u-r\"\n".to_owned(),
            "robots.\"r\".ros2_pose.namespace: 'u-r' is not a ROS name",
        ),
    ];
    for (text, expected) in cases {
        let error = parse(&text, Vec::new()).expect_err(&text);
        assert!(
            error.contains(expected),
            "{text}\n→ {error}\nexpected: {expected}"
        );
    }
    // What works: both schemes, both robot rules, the UR driver's topics by default.
    let config = parse(NAMESPACE_SOURCES, Vec::new()).expect("valid");
    assert_eq!(config.sources.len(), 5);
    let SourceRobot::FromKey(rule) = &config.sources[1].robot else {
        panic!("a rule")
    };
    assert_eq!(rule.topic(), "tcp_pose_broadcaster/pose");
    assert_eq!(
        config.sources[4].robot,
        SourceRobot::Fixed("solo".to_owned())
    );
    let config = parse(OUTPUT_CONFIG, Vec::new()).expect("valid");
    assert_eq!(
        config.ros2_pose.of("anyone").unwrap().key("anyone"),
        format!(
            "0/anyone/armtwin/tcp_pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        )
    );
    assert_eq!(
        config.ros2_pose.of("bob").unwrap().key("bob"),
        "bob/armtwin/tcp_pose"
    );
    assert_eq!(
        config.ros2_pose.of("bob").unwrap().tf_prefix,
        "",
        "the robot's own field wins"
    );
    assert_eq!(
        config.ros2_pose.of("bl").unwrap().tf_prefix,
        "alice_",
        "the default's fills in"
    );
    assert!(config.ros2_pose.of("quiet").is_none());
}

/// The `toml` block of the ROS 2 guide (docs/ros2.md) after `marker`.
fn guide_toml(marker: &str) -> String {
    let guide =
        std::fs::read_to_string(data().join("../../../docs/ros2.md")).expect("docs/ros2.md");
    let after = &guide[guide.find(marker).expect("marker")..];
    let block = &after[after.find("```toml\n").expect("a toml block") + 8..];
    block[..block.find("```").expect("its end")].to_owned()
}

#[test]
fn the_ros2_guide_recipes_load_as_documented() {
    let block = guide_toml("The exact lines for a UR driver");
    let recipes: Vec<&str> = block.split("\n\n").collect();
    assert_eq!(recipes.len(), 4, "{block}");
    for (recipe, from_key) in recipes.iter().zip([true, false, true, false]) {
        let config = parse(recipe, Vec::new()).unwrap_or_else(|e| panic!("{recipe}\n→ {e}"));
        assert_eq!(config.sources.len(), 2);
        for source in &config.sources {
            assert_eq!(
                matches!(source.robot, SourceRobot::FromKey(_)),
                from_key,
                "{recipe}"
            );
        }
        let prefixed = recipe.replace(
            "codec = \"ros2\"",
            "codec = \"ros2\"\ntf_prefix = \"alice_\"",
        );
        let config = parse(&prefixed, Vec::new()).expect("with a tf_prefix");
        let ros2 = config.sources[1].ros2.as_ref().expect("ros2");
        assert_eq!(ros2.base_frame, "alice_base");
    }
    // As the guide says: the two bridge recipes combine, the two rmw_zenoh ones do not.
    parse(&format!("{}\n{}", recipes[2], recipes[3]), Vec::new()).expect("bridge forms combine");
    let error = parse(&format!("{}\n{}", recipes[0], recipes[1]), Vec::new()).unwrap_err();
    assert!(error.contains("a sample would be taken twice"), "{error}");
    let pose = guide_toml("**The twin in RViz.**");
    let config = parse(&pose, Vec::new()).expect("the ros2_pose example");
    let fixed = config.ros2_pose.of("ur10e-07").expect("output");
    assert_eq!(
        fixed.key("ur10e-07"),
        format!(
            "0/armtwin/tcp_pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        )
    );
    assert_eq!(
        config
            .ros2_pose
            .of("plant_a/ur7")
            .expect("output")
            .key("plant_a/ur7"),
        format!(
            "0/plant_a/ur7/armtwin/tcp_pose/{POSE_TYPE}/{}",
            ros2::POSE_STAMPED_TYPE_HASH
        )
    );
}

/// The `rmw_zenoh` type hashes armtwin writes into keys are the ones real rclpy reports for a
/// live publisher (`topic_type_hash`, captured by `tools/capture_rclpy_fixtures.py`; the
/// bridge test asserts the live value against the same file).
#[test]
fn type_hashes_are_the_ones_rclpy_reports() {
    let text = std::fs::read_to_string(data().join("rclpy/type_hashes.json")).expect("file");
    let hashes: Value = serde_json::from_str(&text).expect("JSON");
    assert_eq!(
        hashes["sensor_msgs/msg/JointState"],
        ros2::JOINT_STATE_TYPE_HASH
    );
    assert_eq!(
        hashes["geometry_msgs/msg/PoseStamped"],
        ros2::POSE_STAMPED_TYPE_HASH
    );
}
