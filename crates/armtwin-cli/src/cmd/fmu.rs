//! `armtwin fmu build`: one robot packaged as an FMI 2.0 FMU file.
//!
//! Owns finding the files the flags name and the summary line; must not lay out the archive (the
//! library's `fmu_package` does).

use anyhow::{Context, Result};
use armtwin_core::fmi::FmuSettings;
use armtwin_offline::fmu_package::{self, FmuContents, FmuPackageError};

use super::read_text;
use crate::flags::FmuBuildArgs;

pub(super) fn build(args: &FmuBuildArgs) -> Result<()> {
    // The same checks and messages as `armtwin fk`.
    let model = args.robot.load()?;
    let calibration = args
        .robot
        .calibration
        .as_deref()
        .map(|path| -> Result<(String, String)> {
            let name = path
                .file_name()
                .and_then(|name| name.to_str())
                .with_context(|| format!("{}: not a file name in UTF-8", path.display()))?;
            Ok((name.to_owned(), read_text(path)?))
        })
        .transpose()?;
    let settings = FmuSettings {
        guid: String::new(),
        model: args.robot.model.to_ascii_lowercase(),
        calibration_file: calibration.as_ref().map(|(name, _)| name.clone()),
        frame: model.frame(),
        tool: *model.tool(),
    };
    let platform = fmu_package::host_platform().ok_or(FmuPackageError::Platform)?;
    let identifier = fmu_package::model_identifier(&args.out)?;
    let contents = FmuContents::new(
        &identifier,
        settings,
        calibration.as_ref().map(|(_, text)| text.as_str()),
    )?;
    let library_path = fmu_package::find_library(args.library.as_deref(), platform)?;
    let library = std::fs::read(&library_path)
        .with_context(|| format!("cannot read {}", library_path.display()))?;
    fmu_package::write_fmu(&args.out, &contents, &library, platform)?;
    let settings = &contents.settings;
    eprintln!(
        "wrote {}: {}, {}, frame {}, tcp {:?}; modelIdentifier {identifier}, GUID {} (library {})",
        args.out.display(),
        settings.model,
        settings.calibration_file.as_deref().map_or_else(
            || "nominal".to_owned(),
            |name| format!("calibration {name}")
        ),
        settings.frame.as_str(),
        settings.tool.to_ur_pose(),
        settings.guid,
        library_path.display()
    );
    Ok(())
}
