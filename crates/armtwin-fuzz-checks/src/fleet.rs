//! The fleet description (`armtwin acl`, `armtwin certs`, `[service] fleet`), a file an operator
//! writes: any text is a fleet or an error, never a panic; a fleet's access control is a JSON
//! object whose every key expression Zenoh takes, the same for the same text; each robot group
//! is a plain prefix of robot ids with a limit.

use armtwin_access::acl::Fleet;
use zenoh::key_expr::KeyExpr;

/// Runs every check of this parser on one input; panics on a broken invariant.
pub fn check(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    let Ok(fleet) = Fleet::parse(text) else {
        return;
    };
    let section = fleet.access_control();
    assert!(section.is_object(), "{section}");
    let again = Fleet::parse(text).expect("parsed once").access_control();
    assert_eq!(section, again, "the same text gives the same rules");
    for rule in section["rules"].as_array().into_iter().flatten() {
        for key in rule["key_exprs"].as_array().into_iter().flatten() {
            let key = key.as_str().expect("a key expression is a string");
            assert!(
                KeyExpr::try_from(key).is_ok(),
                "a rule's key {key:?} is not one Zenoh takes"
            );
        }
    }
    for (prefix, max_robots) in fleet.robot_groups() {
        assert!(
            prefix.ends_with('/') && !prefix.contains('*'),
            "group {prefix:?}"
        );
        assert!(*max_robots < usize::MAX, "group {prefix:?}: {max_robots}");
    }
}
