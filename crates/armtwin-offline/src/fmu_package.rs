//! `armtwin fmu build`: the FMI 2.0 co-simulation FMU (`.fmu`) of one robot.
//!
//! Two halves: [`FmuContents::new`] and [`model_description`] are pure (text from the settings
//! and the core's variable table, [`armtwin_core::fmi::VARIABLES`]); [`find_library`] and [`write_fmu`]
//! touch the filesystem. The archive holds `modelDescription.xml`, the model-agnostic FMU
//! library as `binaries/<platform>/<modelIdentifier>.<ext>`, and `resources/` with the robot's
//! settings (`armtwin-fmu.toml`) and, when given, its calibration file.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use thiserror::Error;
use uuid::Uuid;
use zip::write::SimpleFileOptions;

use armtwin_core::fmi::{
    FmuSettings, FmuSettingsError, LogCategory, RESOURCE_FILE, ScalarVariable, Unit, VARIABLES,
    Variable,
};

/// Namespace of armtwin's name-based (v5) FMU GUIDs.
const GUID_NAMESPACE: Uuid = Uuid::from_u128(0x5d7c_41a3_9e0b_4f62_8c15_2b7e_a0d4_3f91);

/// File name of the FMU library as Cargo builds it, without the platform's prefix and extension.
const LIBRARY_STEM: &str = "armtwin_fmu";

/// Why an FMU cannot be built.
#[derive(Debug, Error)]
pub enum FmuPackageError {
    /// The FMU library was not found.
    #[error(
        "the FMU library {file} is not next to this armtwin ({folder}); build it with \
         `cargo build --release -p armtwin-fmu` (for target/release/armtwin; `cargo build -p \
         armtwin-fmu` for target/debug), or name it with --library PATH"
    )]
    LibraryNotFound {
        /// The library's file name.
        file: String,
        /// Where it was looked for.
        folder: String,
    },
    /// `--library` names no file.
    #[error("--library {path}: no such file")]
    LibraryMissing {
        /// The path given.
        path: String,
    },
    /// The running executable's path is unknown.
    #[error("cannot locate the running armtwin executable: {error}")]
    Executable {
        /// Why.
        error: std::io::Error,
    },
    /// The host platform has no FMI platform folder name here.
    #[error("armtwin fmu build runs on 64-bit Linux, macOS and Windows only")]
    Platform,
    /// The output name gives no usable model identifier.
    #[error("--out {path}: the file name (without .fmu) must contain a letter, digit or '_'")]
    Identifier {
        /// The path given.
        path: String,
    },
    /// A file could not be read or written (the message carries the cause, so it is no
    /// `source`: `anyhow` would print it twice).
    #[error("cannot write {path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        error: std::io::Error,
    },
    /// The archive could not be written.
    #[error("cannot write {path}: {error}")]
    Zip {
        /// The archive.
        path: String,
        /// Why.
        error: zip::result::ZipError,
    },
    /// The robot cannot be packaged.
    #[error(transparent)]
    Settings(#[from] FmuSettingsError),
}

/// An FMI platform: its `binaries/` folder and how shared libraries are named there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Platform {
    /// The folder under `binaries/` (`linux64`).
    pub folder: &'static str,
    /// Cargo's file name prefix for a cdylib (`lib` on Unix).
    pub library_prefix: &'static str,
    /// The shared library extension (`so`).
    pub extension: &'static str,
}

/// The platform armtwin runs on, which is the one the FMU library next to it was built for.
#[must_use]
pub fn host_platform() -> Option<Platform> {
    let (folder, library_prefix, extension) = if cfg!(target_pointer_width = "64") {
        if cfg!(target_os = "linux") {
            ("linux64", "lib", "so")
        } else if cfg!(target_os = "macos") {
            ("darwin64", "lib", "dylib")
        } else if cfg!(target_os = "windows") {
            ("win64", "", "dll")
        } else {
            return None;
        }
    } else {
        return None;
    };
    Some(Platform {
        folder,
        library_prefix,
        extension,
    })
}

/// The FMU library: `explicit` if given, else the one next to the running executable.
pub fn find_library(
    explicit: Option<&Path>,
    platform: Platform,
) -> Result<PathBuf, FmuPackageError> {
    if let Some(path) = explicit {
        return if path.is_file() {
            Ok(path.to_owned())
        } else {
            Err(FmuPackageError::LibraryMissing {
                path: path.display().to_string(),
            })
        };
    }
    let file = format!(
        "{}{LIBRARY_STEM}.{}",
        platform.library_prefix, platform.extension
    );
    let executable =
        std::env::current_exe().map_err(|error| FmuPackageError::Executable { error })?;
    let folder = executable.parent().unwrap_or(Path::new("."));
    let candidate = folder.join(&file);
    if candidate.is_file() {
        Ok(candidate)
    } else {
        Err(FmuPackageError::LibraryNotFound {
            file,
            folder: folder.display().to_string(),
        })
    }
}

/// The `modelIdentifier` for an FMU written to `out`: the file name without `.fmu`, with every
/// character that may not stand in a C identifier replaced by `_` (and `_` before a leading
/// digit).
pub fn model_identifier(out: &Path) -> Result<String, FmuPackageError> {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut identifier: String = stem
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    if !stem.chars().any(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(FmuPackageError::Identifier {
            path: out.display().to_string(),
        });
    }
    if identifier.starts_with(|c: char| c.is_ascii_digit()) {
        identifier.insert(0, '_');
    }
    Ok(identifier)
}

/// Everything in an FMU but the library: the model description and the resource files, with the
/// GUID filled in.
#[derive(Debug, Clone, PartialEq)]
pub struct FmuContents {
    /// `modelIdentifier` (also the model name and the library's name in the archive).
    pub model_identifier: String,
    /// The settings, GUID included.
    pub settings: FmuSettings,
    /// `modelDescription.xml`.
    pub model_description: String,
    /// Files under `resources/`: name and content.
    pub resources: Vec<(String, Vec<u8>)>,
}

impl FmuContents {
    /// The contents for `settings` (whose `guid` is replaced) and the calibration file's text
    /// (named by `settings.calibration_file`). The GUID is a name-based UUID of everything the
    /// FMU computes from: the same inputs always give the same GUID, any change a new one.
    pub fn new(
        model_identifier: &str,
        mut settings: FmuSettings,
        calibration_text: Option<&str>,
    ) -> Result<Self, FmuPackageError> {
        // What the FMU will build at fmi2Instantiate, checked now.
        settings.robot_model(calibration_text)?;
        settings.guid = String::new();
        let mut fingerprint = model_description(model_identifier, &settings).into_bytes();
        fingerprint.extend(settings.to_toml().bytes());
        fingerprint.extend(calibration_text.unwrap_or_default().bytes());
        settings.guid = format!("{{{}}}", Uuid::new_v5(&GUID_NAMESPACE, &fingerprint));
        let mut resources = vec![(RESOURCE_FILE.to_owned(), settings.to_toml().into_bytes())];
        if let (Some(name), Some(text)) = (&settings.calibration_file, calibration_text) {
            resources.push((name.clone(), text.as_bytes().to_vec()));
        }
        Ok(Self {
            model_identifier: model_identifier.to_owned(),
            model_description: model_description(model_identifier, &settings),
            settings,
            resources,
        })
    }
}

/// `modelDescription.xml` for `settings`: FMI 2.0 co-simulation, the variables of
/// [`VARIABLES`] with units and descriptions, the tool parameters starting at the settings' tool,
/// and the model structure (every output depends on every joint; initially also on the tool).
#[must_use]
pub fn model_description(model_identifier: &str, settings: &FmuSettings) -> String {
    let calibration = settings.calibration_file.as_deref().map_or_else(
        || "nominal DH".to_owned(),
        |file| format!("calibration {file}"),
    );
    let description = format!(
        "{} forward kinematics and inverse dynamics (armtwin): joint angles q1..q6 in, TCP pose \
         out; with velocities qd1..qd6 and accelerations qdd1..qdd6 in, joint torques tau1..tau6 \
         out (payload_* parameters); {calibration}, frame {}",
        settings.model,
        settings.frame.as_str()
    );
    let identifier = xml_escape(model_identifier);
    let mut xml = String::new();
    // `write!` into a String cannot fail.
    let _ = write!(
        xml,
        r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription
  fmiVersion="2.0"
  modelName="{identifier}"
  guid="{guid}"
  description="{description}"
  generationTool="armtwin {version}"
  variableNamingConvention="flat"
  numberOfEventIndicators="0">
  <CoSimulation
    modelIdentifier="{identifier}"
    needsExecutionTool="false"
    canHandleVariableCommunicationStepSize="true"
    canInterpolateInputs="false"
    maxOutputDerivativeOrder="0"
    canRunAsynchronuously="false"
    canBeInstantiatedOnlyOncePerProcess="false"
    canNotUseMemoryManagementFunctions="true"
    canGetAndSetFMUstate="false"
    canSerializeFMUstate="false"
    providesDirectionalDerivative="false"/>
  <UnitDefinitions>
"#,
        guid = xml_escape(&settings.guid),
        description = xml_escape(&description),
        version = env!("CARGO_PKG_VERSION"),
    );
    for unit in Unit::ALL {
        let exponents: Vec<String> = unit
            .base_units()
            .iter()
            .map(|(base, exponent)| format!(r#"{base}="{exponent}""#))
            .collect();
        let _ = write!(
            xml,
            "    <Unit name=\"{}\">\n      <BaseUnit {}/>\n    </Unit>\n",
            unit.as_str(),
            exponents.join(" ")
        );
    }
    xml.push_str("  </UnitDefinitions>\n  <LogCategories>\n");
    for category in LogCategory::ALL {
        let _ = writeln!(
            xml,
            r#"    <Category name="{}" description="{}"/>"#,
            category.name(),
            xml_escape(category.description())
        );
    }
    xml.push_str("  </LogCategories>\n  <ModelVariables>\n");
    let tool = settings.tool.to_ur_pose();
    for variable in &VARIABLES {
        let _ = write!(xml, "{}", scalar_variable_xml(variable, &tool));
    }
    xml.push_str("  </ModelVariables>\n  <ModelStructure>\n");
    xml.push_str(&model_structure_xml());
    xml.push_str("  </ModelStructure>\n</fmiModelDescription>\n");
    xml
}

/// The `<ModelStructure>` body: each output's dependencies by 1-based variable index.
fn model_structure_xml() -> String {
    let mut xml = String::new();
    let index = |v: &ScalarVariable| v.variable.value_reference() + 1;
    let indices = |keep: fn(Variable) -> bool| {
        VARIABLES
            .iter()
            .filter(|v| keep(v.variable))
            .map(|v| index(v).to_string())
            .collect::<Vec<_>>()
            .join(" ")
    };
    let joints = indices(|v| matches!(v, Variable::Joint(_)));
    let joints_and_tool = indices(|v| matches!(v, Variable::Joint(_) | Variable::Tool(_)));
    let state = indices(|v| {
        matches!(
            v,
            Variable::Joint(_) | Variable::Velocity(_) | Variable::Acceleration(_)
        )
    });
    let state_and_payload = indices(|v| {
        matches!(
            v,
            Variable::Joint(_)
                | Variable::Velocity(_)
                | Variable::Acceleration(_)
                | Variable::Payload(_)
        )
    });
    // The pose depends on the angles (and initially the tool), the torques on the joint state
    // (and initially the payload).
    for (section, pose, torque) in [
        ("Outputs", &joints, &state),
        ("InitialUnknowns", &joints_and_tool, &state_and_payload),
    ] {
        let _ = writeln!(xml, "    <{section}>");
        for output in &VARIABLES {
            let dependencies = match output.variable {
                Variable::Output(_) => pose,
                Variable::Torque(_) => torque,
                _ => continue,
            };
            let _ = writeln!(
                xml,
                r#"      <Unknown index="{}" dependencies="{dependencies}"/>"#,
                index(output)
            );
        }
        let _ = writeln!(xml, "    </{section}>");
    }
    xml
}

/// One `<ScalarVariable>`; `tool` gives the tool parameters' start values.
fn scalar_variable_xml(variable: &ScalarVariable, tool: &[f64; 6]) -> String {
    let (attributes, start) = match variable.variable {
        Variable::Joint(_) | Variable::Velocity(_) | Variable::Acceleration(_) => {
            (r#"causality="input" variability="continuous""#, Some(0.0))
        }
        Variable::Output(_) | Variable::Torque(_) => (
            r#"causality="output" variability="continuous" initial="calculated""#,
            None,
        ),
        Variable::Tool(index) => (
            r#"causality="parameter" variability="tunable" initial="exact""#,
            Some(tool[index]),
        ),
        Variable::Payload(_) => (
            r#"causality="parameter" variability="tunable" initial="exact""#,
            Some(0.0),
        ),
    };
    let unit = variable
        .unit
        .map(|unit| format!(r#" unit="{}""#, unit.as_str()))
        .unwrap_or_default();
    // `{:?}` prints the shortest text that parses back to the same f64.
    let start = start
        .map(|value| format!(r#" start="{value:?}""#))
        .unwrap_or_default();
    format!(
        "    <ScalarVariable name=\"{}\" valueReference=\"{}\" description=\"{}\" {attributes}>\n      <Real{unit}{start}/>\n    </ScalarVariable>\n",
        variable.name,
        variable.variable.value_reference(),
        xml_escape(variable.description),
    )
}

/// `text` with the five XML special characters escaped, for attribute values.
fn xml_escape(text: &str) -> String {
    let mut escaped = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => escaped.push_str("&amp;"),
            '<' => escaped.push_str("&lt;"),
            '>' => escaped.push_str("&gt;"),
            '"' => escaped.push_str("&quot;"),
            '\'' => escaped.push_str("&apos;"),
            _ => escaped.push(c),
        }
    }
    escaped
}

/// Writes the FMU archive to `out`: `contents` and `library` (the FMU library's bytes) as
/// `binaries/<platform>/<modelIdentifier>.<ext>`. Entries are deflated and dated 1980-01-01,
/// so the same inputs give the same bytes.
pub fn write_fmu(
    out: &Path,
    contents: &FmuContents,
    library: &[u8],
    platform: Platform,
) -> Result<(), FmuPackageError> {
    let zip_error = |error| FmuPackageError::Zip {
        path: out.display().to_string(),
        error,
    };
    let io_error = |error| FmuPackageError::Io {
        path: out.display().to_string(),
        error,
    };
    let file = std::fs::File::create(out).map_err(io_error)?;
    let mut archive = zip::ZipWriter::new(std::io::BufWriter::new(file));
    let options = SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .last_modified_time(zip::DateTime::default());
    let mut entries: Vec<(String, &[u8], u32)> = vec![(
        "modelDescription.xml".to_owned(),
        contents.model_description.as_bytes(),
        0o644,
    )];
    entries.push((
        format!(
            "binaries/{}/{}.{}",
            platform.folder, contents.model_identifier, platform.extension
        ),
        library,
        0o755,
    ));
    for (name, bytes) in &contents.resources {
        entries.push((format!("resources/{name}"), bytes, 0o644));
    }
    for (name, bytes, mode) in entries {
        archive
            .start_file(name, options.unix_permissions(mode))
            .map_err(zip_error)?;
        archive.write_all(bytes).map_err(io_error)?;
    }
    archive
        .finish()
        .map_err(zip_error)?
        .flush()
        .map_err(io_error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use armtwin_core::kinematics::{OutputFrame, TcpOffset};

    fn settings(tool: [f64; 6]) -> FmuSettings {
        FmuSettings {
            guid: String::new(),
            model: "ur10e".to_owned(),
            calibration_file: None,
            frame: OutputFrame::Base,
            tool: TcpOffset::from_ur_pose(tool).expect("finite"),
        }
    }

    #[test]
    fn identifiers_are_c_identifiers_from_the_file_name() {
        let id = |path: &str| model_identifier(Path::new(path));
        assert_eq!(id("out/UR10e_FK.fmu").expect("valid"), "UR10e_FK");
        assert_eq!(id("my robot-2.fmu").expect("valid"), "my_robot_2");
        assert_eq!(id("3arm.fmu").expect("valid"), "_3arm");
        assert!(id("+++.fmu").is_err());
        assert!(id("").is_err());
    }

    #[test]
    fn model_structure_indices_are_one_based_positions() {
        let xml = model_description("UR10e_FK", &settings([0.0; 6]));
        let positions: Vec<&str> = xml
            .match_indices("<ScalarVariable name=\"")
            .map(|(at, m)| {
                let rest = &xml[at + m.len()..];
                &rest[..rest.find('"').expect("closing quote")]
            })
            .collect();
        assert_eq!(positions.len(), 44);
        assert_eq!(positions[34], "tau1");
        assert_eq!(positions[6], "x");
        // The first output, x, is the 7th ScalarVariable.
        assert!(xml.contains(r#"<Unknown index="7" dependencies="1 2 3 4 5 6"/>"#));
        assert!(
            xml.contains(r#"<Unknown index="16" dependencies="1 2 3 4 5 6 17 18 19 20 21 22"/>"#)
        );
        assert!(!xml.contains(r#"index="17""#));
        // tau1, the 35th: on q, qd and qdd; initially also on the payload.
        let state: Vec<String> = (1..=6).chain(23..=34).map(|i| i.to_string()).collect();
        let state = state.join(" ");
        assert!(xml.contains(&format!(r#"<Unknown index="35" dependencies="{state}"/>"#)));
        assert!(xml.contains(&format!(
            r#"<Unknown index="40" dependencies="{state} 41 42 43 44"/>"#
        )));
    }

    #[test]
    fn tool_start_values_round_trip_and_guids_follow_the_contents() {
        let tool = [0.1, -0.025, 0.15, 1e-17, 0.3, -2.0];
        let contents = FmuContents::new("A", settings(tool), None).expect("valid");
        assert!(
            contents
                .model_description
                .contains(r#"name="tcp_rx" valueReference="19""#)
        );
        assert!(contents.model_description.contains(r#"start="1e-17""#));
        assert!(contents.model_description.contains(r#"start="-0.025""#));
        assert!(
            contents
                .model_description
                .contains(&format!("guid=\"{}\"", contents.settings.guid))
        );
        let again = FmuContents::new("A", settings(tool), None).expect("valid");
        assert_eq!(again, contents);
        let other_tool = FmuContents::new("A", settings([0.0; 6]), None).expect("valid");
        assert_ne!(other_tool.settings.guid, contents.settings.guid);
        let other_name = FmuContents::new("B", settings(tool), None).expect("valid");
        assert_ne!(other_name.settings.guid, contents.settings.guid);
        let resource = String::from_utf8(contents.resources[0].1.clone()).expect("UTF-8");
        assert_eq!(
            FmuSettings::from_toml(&resource).expect("valid"),
            contents.settings
        );
    }

    #[test]
    fn escapes_attribute_text() {
        assert_eq!(xml_escape(r#"a<b>&"c'"#), "a&lt;b&gt;&amp;&quot;c&apos;");
    }
}
