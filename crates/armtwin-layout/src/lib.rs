//! The workspace's layout, checked: this crate has tests only (`tests/`), and neither depends on
//! a crate of the workspace nor is depended on.
