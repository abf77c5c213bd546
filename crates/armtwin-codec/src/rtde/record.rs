//! RTDE samples as the CSV `ur_rtde` records (`RTDEReceiveInterface::startFileRecording`): a
//! header of RTDE names, vectors as `<name>_0`…, then one row per data package, numbers in their
//! shortest form that reads back to the same `f64`. `armtwin validate` and `calibrate` read it
//! (`recording`'s RTDE layout). Must not open the file: the caller writes the text.

use std::fmt::Write as _;

use super::recipe::{Cell, Recipe, RtdeSample};

/// The header line (without its newline) of a recording of `recipe`'s variables.
#[must_use]
pub fn header(recipe: &Recipe) -> String {
    let mut line = String::new();
    for variable in &recipe.variables {
        let width = variable.width();
        for index in 0..width {
            if !line.is_empty() {
                line.push(',');
            }
            line.push_str(variable.name);
            if width > 1 {
                let _ = write!(line, "_{index}");
            }
        }
    }
    line
}

/// Appends `sample`'s row (without its newline) under `recipe` to `line`.
pub fn write_row(recipe: &Recipe, sample: &RtdeSample, line: &mut String) {
    let mut first = true;
    for variable in &recipe.variables {
        variable.cells(sample, |cell| {
            if !first {
                line.push(',');
            }
            first = false;
            // `Display` of an `f64` is its shortest round-trip form; writing to a `String`
            // cannot fail.
            let _ = match cell {
                Cell::Double(value) => write!(line, "{value}"),
                Cell::Integer(value) => write!(line, "{value}"),
            };
        });
    }
}
