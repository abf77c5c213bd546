//! A user's configuration file layered over the embedded default (`config/armtwin.toml`), so that
//! a key the file leaves out keeps the value the default documents.
//!
//! Owns the merge of TOML tables, which `[zenoh]` keys the user's file writes itself (a
//! `[zenoh] file` and a client's listeners are settled from that, by the mesh crate's
//! `ZenohSection::layered`), and the effective configuration `armtwin config show` prints. Must
//! not check values: `super` deserializes the merged table into its sections and checks them
//! there.

use toml::{Table, Value};

use super::WrittenKeys;

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

/// The user's table over the default's, and which of `[zenoh]`'s `mode`, `listen` and `connect`
/// the user's table writes itself: what it leaves out, a `[zenoh] file` may set before the
/// default's value stands (`ZenohSection::layered`).
pub(super) fn effective(default: Table, user: Table) -> (Table, WrittenKeys) {
    let user_zenoh = user.get("zenoh").and_then(Value::as_table);
    let writes = |key: &str| user_zenoh.is_some_and(|zenoh| zenoh.contains_key(key));
    let written = WrittenKeys {
        mode: writes("mode"),
        listen: writes("listen"),
        connect: writes("connect"),
    };
    (layered(default, user), written)
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
    fn the_zenoh_keys_the_users_file_writes_are_told_apart_from_the_defaults() {
        let default = table("[zenoh]\nmode = \"peer\"\nlisten = [\"tcp/127.0.0.1:7447\"]\n");
        let (merged, written) = effective(
            default.clone(),
            table("[zenoh]\nfile = \"z.json5\"\nconnect = []\n"),
        );
        assert_eq!(
            written,
            WrittenKeys {
                mode: false,
                listen: false,
                connect: true,
            }
        );
        assert_eq!(merged["zenoh"]["mode"], Value::from("peer"));
        let (_, nothing) = effective(default, table("[robots.r1]\nmodel = \"ur5e\"\n"));
        assert_eq!(nothing, WrittenKeys::default());
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
