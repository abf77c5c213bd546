//! A user's configuration file layered over the embedded default (`config/armtwin.toml`), so that
//! a key the file leaves out keeps the value the default documents.
//!
//! Owns the merge of TOML tables, the one exception to it (a client's listeners), and the
//! effective configuration `armtwin config show` prints. Must not check values: `super`
//! deserializes the merged table into its sections and checks them there.

use toml::{Table, Value};

use super::ZenohMode;

/// `overlay` over `base`: tables merge key by key at every depth; any other value (a number, a
/// string, an array, `[[sources]]` included) replaces the base's whole.
pub(super) fn layered(mut base: Table, overlay: Table) -> Table {
    for (key, value) in overlay {
        match (base.get_mut(&key), value) {
            (Some(Value::Table(below)), Value::Table(above)) => {
                let merged = layered(std::mem::take(below), above);
                *below = merged;
            }
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
    base
}

/// The user's table over the default's, with the mode the command line gives (`-m`), if any.
///
/// The default's `[zenoh] listen` is a peer's: a client reaches the mesh through what it connects
/// to, and listens only where the user's own file says (or `-l`), as Zenoh's clients do. Without
/// this, every client-mode shard of a fleet would try to bind the default's port on one host.
pub(super) fn effective(default: Table, user: Table, mode_flag: Option<ZenohMode>) -> Table {
    let user_listens = user
        .get("zenoh")
        .and_then(Value::as_table)
        .is_some_and(|zenoh| zenoh.contains_key("listen"));
    let mut merged = layered(default, user);
    let zenoh = merged
        .entry("zenoh")
        .or_insert_with(|| Value::Table(Table::new()));
    if let Value::Table(zenoh) = zenoh {
        let mode = mode_flag.map_or_else(
            || {
                zenoh
                    .get("mode")
                    .and_then(Value::as_str)
                    .unwrap_or(ZenohMode::default().as_str())
                    .to_owned()
            },
            |mode| mode.as_str().to_owned(),
        );
        if mode == ZenohMode::Client.as_str() && !user_listens {
            zenoh.insert("listen".to_owned(), Value::Array(Vec::new()));
        }
    }
    merged
}

/// The effective table with every robot's section completed from `[robots.default]`, as the
/// loader completes it: the robot's own keys first, then the default's; `ros2_pose` key by key.
/// `sensors` belong to one robot and are not inherited.
pub(super) fn with_robots_completed(mut table: Table) -> Table {
    let Some(Value::Table(robots)) = table.get_mut("robots") else {
        return table;
    };
    let Some(Value::Table(default)) = robots.get("default").cloned() else {
        return table;
    };
    let inherited: Table = default
        .into_iter()
        .filter(|(key, _)| key != "sensors")
        .collect();
    for (id, section) in robots.iter_mut() {
        if id == "default" {
            continue;
        }
        if let Value::Table(own) = section {
            *own = layered(inherited.clone(), std::mem::take(own));
        }
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> Table {
        text.parse().expect("valid TOML")
    }

    #[test]
    fn tables_merge_at_every_depth_and_other_values_replace() {
        let base = table(
            "[a]\nx = 1\ny = [1, 2]\n[a.inner]\np = 1\nq = 2\n[[list]]\nv = 1\n[[list]]\nv = 2\n",
        );
        let overlay = table("[a]\ny = [3]\n[a.inner]\nq = 5\n[[list]]\nv = 9\n[b]\nz = true\n");
        assert_eq!(
            layered(base, overlay),
            table("[a]\nx = 1\ny = [3]\n[a.inner]\np = 1\nq = 5\n[[list]]\nv = 9\n[b]\nz = true\n")
        );
    }

    #[test]
    fn a_client_listens_only_where_its_own_file_or_flags_say() {
        let default = table("[zenoh]\nmode = \"peer\"\nlisten = [\"tcp/127.0.0.1:7447\"]\n");
        let listen = |merged: &Table| merged["zenoh"]["listen"].clone();
        let peer = effective(default.clone(), Table::new(), None);
        assert_eq!(
            listen(&peer),
            Value::Array(vec!["tcp/127.0.0.1:7447".into()])
        );
        let by_flag = effective(default.clone(), Table::new(), Some(ZenohMode::Client));
        assert_eq!(listen(&by_flag), Value::Array(Vec::new()));
        let by_file = effective(default.clone(), table("[zenoh]\nmode = \"client\"\n"), None);
        assert_eq!(listen(&by_file), Value::Array(Vec::new()));
        let told = effective(
            default,
            table("[zenoh]\nmode = \"client\"\nlisten = [\"tcp/127.0.0.1:7000\"]\n"),
            None,
        );
        assert_eq!(
            listen(&told),
            Value::Array(vec!["tcp/127.0.0.1:7000".into()])
        );
    }

    #[test]
    fn robots_are_completed_from_the_default_but_for_their_sensors() {
        let merged = table(
            "[robots.default]\nmodel = \"ur10e\"\nframe = \"base\"\n\
             ros2_pose = { scheme = \"bridge\", topic = \"t\" }\n\
             [[robots.default.sensors]]\nkey_expr = \"x\"\n\
             [robots.r1]\nmodel = \"ur5e\"\nros2_pose = { topic = \"own\" }\n",
        );
        let completed = with_robots_completed(merged);
        assert_eq!(
            completed["robots"]["r1"],
            Value::Table(table(
                "model = \"ur5e\"\nframe = \"base\"\nros2_pose = { scheme = \"bridge\", topic = \"own\" }\n"
            ))
        );
    }
}
