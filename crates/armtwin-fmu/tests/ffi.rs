//! The exported `fmi2*` C functions called as a master would (through the rlib): lifecycle,
//! outputs equal to the core's forward kinematics, independent instances, and every kind of bad
//! call returning an error status and reaching the master's logger.
#![allow(
    clippy::expect_used,
    clippy::unwrap_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]
#![allow(
    unsafe_code,
    reason = "calling the FMU's C API means passing raw pointers, as a C master does"
)]
#![allow(
    clippy::float_cmp,
    reason = "the FMU must give the core's values exactly"
)]

use std::ffi::{CStr, CString, c_char, c_int, c_void};
use std::path::Path;
use std::ptr;
use std::sync::Mutex;

use armtwin_core::fmi::{FmuSettings, RESOURCE_FILE};
use armtwin_core::kinematics::{OutputFrame, TcpOffset};
use armtwin_core::pose_fields::PoseFields;
use armtwin_fmu::ffi::{
    FMI2_DISCARD, FMI2_ERROR, FMI2_OK, Fmi2CallbackFunctions, Fmi2CallbackLogger, Fmi2Component,
    fmi2DoStep, fmi2EnterInitializationMode, fmi2ExitInitializationMode, fmi2FreeInstance,
    fmi2GetBoolean, fmi2GetFMUstate, fmi2GetReal, fmi2GetRealStatus, fmi2GetStatus,
    fmi2GetTypesPlatform, fmi2GetVersion, fmi2Instantiate, fmi2Reset, fmi2SetDebugLogging,
    fmi2SetReal, fmi2SetupExperiment, fmi2Terminate,
};

const CALIBRATION: &str = include_str!("../../../config/examples/calibration.conf");
const OUTPUT_VRS: [u32; 10] = [6, 7, 8, 9, 10, 11, 12, 13, 14, 15];
const JOINT_VRS: [u32; 6] = [0, 1, 2, 3, 4, 5];
const GUID: &str = "{00000000-0000-5000-8000-0000000000aa}";

/// One logger call.
#[derive(Debug, Clone)]
struct LogLine {
    status: c_int,
    category: String,
    message: String,
}

/// The master's side of the log: what the FMU sent.
#[derive(Default)]
struct Log {
    lines: Mutex<Vec<LogLine>>,
}

impl Log {
    fn take(&self) -> Vec<LogLine> {
        std::mem::take(&mut *self.lines.lock().expect("not poisoned"))
    }
}

/// A logger that reads exactly the FMU's one variadic argument: the FMU must call it with the
/// format "%s" and the message as that argument.
extern "C" fn record(
    environment: *mut c_void,
    _instance_name: *const c_char,
    status: c_int,
    category: *const c_char,
    format: *const c_char,
    message: *const c_char,
) {
    // SAFETY: the FMU passes back our environment (a `&Log` that outlives every instance) and
    // NUL-terminated strings.
    let (log, category, format, message) = unsafe {
        (
            &*environment.cast::<Log>(),
            CStr::from_ptr(category),
            CStr::from_ptr(format),
            CStr::from_ptr(message),
        )
    };
    assert_eq!(format, c"%s", "the message must never be the format");
    log.lines.lock().expect("not poisoned").push(LogLine {
        status,
        category: category.to_string_lossy().into_owned(),
        message: message.to_string_lossy().into_owned(),
    });
}

fn callbacks(log: &Log) -> Fmi2CallbackFunctions {
    let record: extern "C" fn(
        *mut c_void,
        *const c_char,
        c_int,
        *const c_char,
        *const c_char,
        *const c_char,
    ) = record;
    // SAFETY: on the C ABIs this test runs on (x86-64 System V, AArch64 Linux), a variadic call
    // passes its pointer and integer arguments exactly as a call of a non-variadic function with
    // those parameters; `record` reads the fixed arguments and the one variadic pointer the FMU
    // passes. Stable Rust cannot define a C-variadic function.
    let logger: Fmi2CallbackLogger = unsafe { std::mem::transmute(record) };
    Fmi2CallbackFunctions {
        logger: Some(logger),
        allocate_memory: None,
        free_memory: None,
        step_finished: None,
        component_environment: ptr::from_ref(log).cast_mut().cast(),
    }
}

/// An unpacked FMU's resource folder for `settings` (and the example calibration when named).
fn resources(settings: &FmuSettings) -> tempfile::TempDir {
    let dir = tempfile::Builder::new()
        .prefix("armtwin fmu ")
        .tempdir()
        .expect("temp dir");
    std::fs::write(dir.path().join(RESOURCE_FILE), settings.to_toml()).expect("write");
    if let Some(name) = &settings.calibration_file {
        std::fs::write(dir.path().join(name), CALIBRATION).expect("write");
    }
    dir
}

fn settings(model: &str, calibration: bool, tool: [f64; 6], frame: OutputFrame) -> FmuSettings {
    FmuSettings {
        guid: GUID.to_owned(),
        model: model.to_owned(),
        calibration_file: calibration.then(|| "calibration.conf".to_owned()),
        frame,
        tool: TcpOffset::from_ur_pose(tool).expect("finite"),
    }
}

/// `file://` URI of `path`, with the space percent-encoded (as Python's `as_uri` does).
fn uri(path: &Path) -> CString {
    CString::new(format!("file://{}", path.display()).replace(' ', "%20")).expect("no NUL")
}

fn instantiate(
    name: &str,
    guid: &str,
    location: &CString,
    log: &Log,
    kind: c_int,
) -> Fmi2Component {
    let name = CString::new(name).expect("no NUL");
    let guid = CString::new(guid).expect("no NUL");
    let functions = callbacks(log);
    // SAFETY: valid C strings and callback struct for the duration of the call.
    unsafe {
        fmi2Instantiate(
            name.as_ptr(),
            kind,
            guid.as_ptr(),
            location.as_ptr(),
            &raw const functions,
            0,
            0,
        )
    }
}

fn get(c: Fmi2Component, vrs: &[u32]) -> Vec<f64> {
    let mut values = vec![f64::NAN; vrs.len()];
    // SAFETY: arrays of `vrs.len()` elements.
    let status = unsafe { fmi2GetReal(c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr()) };
    assert_eq!(status, FMI2_OK, "fmi2GetReal");
    values
}

fn set(c: Fmi2Component, vrs: &[u32], values: &[f64]) -> c_int {
    assert_eq!(vrs.len(), values.len());
    // SAFETY: arrays of `vrs.len()` elements.
    unsafe { fmi2SetReal(c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
}

fn initialize(c: Fmi2Component) {
    // SAFETY: `c` is a live instance.
    unsafe {
        assert_eq!(fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0), FMI2_OK);
        assert_eq!(fmi2EnterInitializationMode(c), FMI2_OK);
        assert_eq!(fmi2ExitInitializationMode(c), FMI2_OK);
    }
}

fn core_outputs(settings: &FmuSettings, q: &[f64; 6]) -> Vec<f64> {
    let calibration = settings.calibration_file.as_ref().map(|_| CALIBRATION);
    let model = settings.robot_model(calibration).expect("valid robot");
    PoseFields::from(&model.pose(q).expect("valid joints").readout())
        .values()
        .to_vec()
}

/// Joint angles along a sample path (radians, within the limits).
fn path(step: usize) -> [f64; 6] {
    let s = step as f64 * 0.37;
    [
        s.sin() * 3.0,
        -1.2 + 0.8 * s.cos(),
        1.1 * (0.5 * s).sin(),
        -0.4 + s.cos(),
        1.5 - 0.3 * s.sin(),
        (2.0 * s).cos() * 6.0,
    ]
}

#[test]
fn version_and_platform() {
    // SAFETY: both return static C strings.
    unsafe {
        assert_eq!(CStr::from_ptr(fmi2GetVersion()), c"2.0");
        assert_eq!(CStr::from_ptr(fmi2GetTypesPlatform()), c"default");
    }
}

#[test]
fn outputs_equal_the_core_pose_from_initialization_through_every_step() {
    let log = Log::default();
    let settings = settings(
        "ur10e",
        true,
        [0.01, -0.02, 0.15, 0.1, -0.2, 0.3],
        OutputFrame::BaseLink,
    );
    let dir = resources(&settings);
    let c = instantiate("arm", GUID, &uri(dir.path()), &log, 1);
    assert!(!c.is_null(), "{:?}", log.take());
    // SAFETY: `c` is a live instance.
    unsafe {
        assert_eq!(fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0), FMI2_OK);
        assert_eq!(fmi2EnterInitializationMode(c), FMI2_OK);
    }
    // Before any input is set: the pose at the start values (all joints 0).
    assert_eq!(get(c, &OUTPUT_VRS), core_outputs(&settings, &[0.0; 6]));
    assert_eq!(set(c, &JOINT_VRS, &path(0)), FMI2_OK);
    assert_eq!(get(c, &OUTPUT_VRS), core_outputs(&settings, &path(0)));
    // SAFETY: `c` is a live instance.
    assert_eq!(unsafe { fmi2ExitInitializationMode(c) }, FMI2_OK);
    assert_eq!(get(c, &OUTPUT_VRS), core_outputs(&settings, &path(0)));
    let mut t = 0.0;
    for step in 1..200 {
        assert_eq!(set(c, &JOINT_VRS, &path(step)), FMI2_OK);
        // SAFETY: `c` is a live instance.
        assert_eq!(unsafe { fmi2DoStep(c, t, 0.002, 1) }, FMI2_OK);
        t = step as f64 * 0.002;
        assert_eq!(
            get(c, &OUTPUT_VRS),
            core_outputs(&settings, &path(step)),
            "step {step}"
        );
        assert_eq!(get(c, &JOINT_VRS), path(step));
    }
    let mut last = f64::NAN;
    // SAFETY: `c` is a live instance; `last` is writable.
    unsafe {
        assert_eq!(fmi2GetRealStatus(c, 2, &raw mut last), FMI2_OK);
        assert_eq!(fmi2Terminate(c), FMI2_OK);
        fmi2FreeInstance(c);
    }
    assert!((last - 199.0 * 0.002).abs() < 1e-12);
    assert!(log.take().is_empty(), "no errors, no debug logging");
}

#[test]
fn two_instances_do_not_share_state() {
    let log = Log::default();
    let ur10e = settings("ur10e", false, [0.0; 6], OutputFrame::Base);
    let ur5e = settings(
        "ur5e",
        true,
        [0.0, 0.0, 0.2, 0.0, 0.0, 0.0],
        OutputFrame::Base,
    );
    let (dir_a, dir_b) = (resources(&ur10e), resources(&ur5e));
    let a = instantiate("a", GUID, &uri(dir_a.path()), &log, 1);
    let b = instantiate("b", GUID, &uri(dir_b.path()), &log, 1);
    assert!(!a.is_null() && !b.is_null() && a != b, "{:?}", log.take());
    initialize(a);
    initialize(b);
    assert_eq!(set(a, &JOINT_VRS, &path(1)), FMI2_OK);
    assert_eq!(set(b, &JOINT_VRS, &path(2)), FMI2_OK);
    assert_eq!(set(b, &[18], &[0.3]), FMI2_OK);
    let ur5e_longer_tool = FmuSettings {
        tool: TcpOffset::from_ur_pose([0.0, 0.0, 0.3, 0.0, 0.0, 0.0]).expect("finite"),
        ..ur5e.clone()
    };
    assert_eq!(get(a, &OUTPUT_VRS), core_outputs(&ur10e, &path(1)));
    assert_eq!(
        get(b, &OUTPUT_VRS),
        core_outputs(&ur5e_longer_tool, &path(2))
    );
    assert_eq!(get(a, &[18]), [0.0]);
    // An error in one leaves the other working.
    assert_eq!(set(a, &[6], &[1.0]), FMI2_ERROR);
    // SAFETY: live instances.
    unsafe {
        assert_eq!(fmi2DoStep(a, 0.0, 0.1, 1), FMI2_ERROR);
        assert_eq!(fmi2DoStep(b, 0.0, 0.1, 1), FMI2_OK);
        fmi2FreeInstance(a);
    }
    assert_eq!(
        get(b, &OUTPUT_VRS),
        core_outputs(&ur5e_longer_tool, &path(2))
    );
    // SAFETY: `b` is live; freed once.
    unsafe { fmi2FreeInstance(b) };
}

#[test]
fn bad_calls_return_error_log_it_and_need_a_reset() {
    let log = Log::default();
    let settings = settings("ur10e", false, [0.0; 6], OutputFrame::Base);
    let dir = resources(&settings);
    let c = instantiate("arm #1", GUID, &uri(dir.path()), &log, 1);
    assert!(!c.is_null());
    let expect_error = |status: c_int, fragment: &str| {
        assert_eq!(status, FMI2_ERROR, "{fragment}");
        let lines = log.take();
        assert_eq!(lines.len(), 1, "{fragment}: {lines:?}");
        assert_eq!(lines[0].status, FMI2_ERROR);
        assert_eq!(lines[0].category, "logStatusError");
        assert!(
            lines[0].message.contains(fragment),
            "{:?}",
            lines[0].message
        );
    };
    // SAFETY: `c` is live; every pointer is valid or deliberately null with a count the FMU
    // must check before reading.
    unsafe {
        // Wrong state: no step before initialization.
        expect_error(
            fmi2DoStep(c, 0.0, 0.1, 1),
            "fmi2DoStep: not allowed in state instantiated",
        );
        // In the error state, only getters, logging, reset and free.
        expect_error(
            fmi2EnterInitializationMode(c),
            "error (an earlier call failed",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        expect_error(
            set(c, &[99], &[0.0]),
            "no Real variable has value reference 99",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        expect_error(
            set(c, &[0, 9], &[0.1, 0.2]),
            "'roll' (value reference 9) is an output",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        expect_error(set(c, &[3], &[f64::NAN]), "joint q4 is not a finite number");
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        let mut value = 0.0;
        expect_error(
            fmi2GetReal(c, ptr::null(), 1, &raw mut value),
            "fmi2GetReal: argument 'vr' is a null pointer",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        expect_error(
            fmi2SetReal(c, JOINT_VRS.as_ptr(), 6, ptr::null()),
            "fmi2SetReal: argument 'value' is a null pointer",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        let mut flag = 0;
        expect_error(
            fmi2GetBoolean(c, [0u32].as_ptr(), 1, &raw mut flag),
            "no Boolean variable has value reference 0",
        );
        // Zero value references with null arrays are fine.
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        assert_eq!(fmi2GetReal(c, ptr::null(), 0, ptr::null_mut()), FMI2_OK);
        expect_error(
            fmi2DoStep(c, 5.0, 0.1, 1),
            "currentCommunicationPoint 5 is not the FMU's time 0",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        let mut state = ptr::null_mut();
        expect_error(
            fmi2GetFMUstate(c, &raw mut state),
            "fmi2GetFMUstate is not supported by this FMU (canGetAndSetFMUstate=\"false\")",
        );
        assert_eq!(fmi2Reset(c), FMI2_OK);
        initialize(c);
        let mut status = FMI2_OK;
        assert_eq!(fmi2GetStatus(c, 0, &raw mut status), FMI2_DISCARD);
        let lines = log.take();
        assert_eq!(lines[0].category, "logStatusDiscard");
        assert!(lines[0].message.contains("status kind 0 is not available"));
        // A discard is no error: stepping goes on.
        assert_eq!(fmi2DoStep(c, 0.0, 0.1, 1), FMI2_OK);
        let unknown = [c"logEverything".as_ptr()];
        expect_error(
            fmi2SetDebugLogging(c, 1, 1, unknown.as_ptr()),
            "unknown log category 'logEverything'",
        );
        fmi2FreeInstance(c);
    }
}

#[test]
fn debug_logging_reports_calls_and_escapes_hashes() {
    let log = Log::default();
    let settings = settings("ur3e", false, [0.0; 6], OutputFrame::Base);
    let dir = resources(&settings);
    let c = instantiate("arm", GUID, &uri(dir.path()), &log, 1);
    // SAFETY: `c` is live.
    unsafe {
        assert_eq!(fmi2SetDebugLogging(c, 1, 0, ptr::null()), FMI2_OK);
        initialize(c);
        assert_eq!(fmi2DoStep(c, 0.0, 0.5, 1), FMI2_OK);
        fmi2FreeInstance(c);
    }
    let lines = log.take();
    let messages: Vec<_> = lines.iter().map(|l| l.message.as_str()).collect();
    assert!(
        lines
            .iter()
            .all(|l| l.category == "logCalls" && l.status == FMI2_OK)
    );
    assert!(
        messages.contains(&"fmi2ExitInitializationMode: now step complete"),
        "{messages:?}"
    );
    assert!(messages.contains(&"fmi2DoStep: 0 + 0.5"), "{messages:?}");

    let log = Log::default();
    let missing = CString::new("file:///no/such/dir%23%25s").expect("no NUL");
    assert!(instantiate("arm", GUID, &missing, &log, 1).is_null());
    let lines = log.take();
    // '#' is doubled (FMI's escape for value references); '%' arrives as it is.
    assert!(
        lines[0]
            .message
            .contains("/no/such/dir##%s/armtwin-fmu.toml"),
        "{lines:?}"
    );
}

#[test]
fn instantiate_refuses_what_it_cannot_serve_and_says_why() {
    let log = Log::default();
    let settings = settings("ur10e", false, [0.0; 6], OutputFrame::Base);
    let dir = resources(&settings);
    let location = uri(dir.path());
    let refused = |name: &str, guid: &str, location: &CString, kind: c_int, fragment: &str| {
        assert!(
            instantiate(name, guid, location, &log, kind).is_null(),
            "{fragment}"
        );
        let lines = log.take();
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert_eq!(lines[0].status, FMI2_ERROR);
        assert!(
            lines[0].message.contains(fragment),
            "{:?}",
            lines[0].message
        );
    };
    refused(
        "arm",
        "{other}",
        &location,
        1,
        "fmuGUID {other} does not match this FMU's",
    );
    refused("arm", GUID, &location, 0, "fmuType 0 is not supported");
    refused("", GUID, &location, 1, "instanceName is empty");
    refused(
        "arm",
        GUID,
        &CString::new(dir.path().display().to_string()).expect("no NUL"),
        1,
        "is not a file URI",
    );
    std::fs::write(dir.path().join(RESOURCE_FILE), "model = 3").expect("write");
    refused("arm", GUID, &location, 1, "armtwin-fmu.toml: ");

    // Null arguments: logged when the logger is known, never a crash.
    let functions = callbacks(&log);
    // SAFETY: null pointers where the FMU must check; valid ones elsewhere.
    unsafe {
        let c = fmi2Instantiate(
            c"arm".as_ptr(),
            1,
            ptr::null(),
            location.as_ptr(),
            &raw const functions,
            0,
            0,
        );
        assert!(c.is_null());
        assert!(
            log.take()[0]
                .message
                .contains("'fmuGUID' is a null pointer")
        );
        let c = fmi2Instantiate(
            c"arm".as_ptr(),
            1,
            c"g".as_ptr(),
            location.as_ptr(),
            ptr::null(),
            0,
            0,
        );
        assert!(c.is_null());
    }
}

#[test]
fn a_null_instance_is_an_error_everywhere() {
    let mut value = 0.0;
    // SAFETY: null instances, which the FMU must refuse before reading anything.
    unsafe {
        assert_eq!(fmi2EnterInitializationMode(ptr::null_mut()), FMI2_ERROR);
        assert_eq!(fmi2DoStep(ptr::null_mut(), 0.0, 0.1, 0), FMI2_ERROR);
        assert_eq!(fmi2Reset(ptr::null_mut()), FMI2_ERROR);
        assert_eq!(
            fmi2GetReal(ptr::null_mut(), [6u32].as_ptr(), 1, &raw mut value),
            FMI2_ERROR
        );
        fmi2FreeInstance(ptr::null_mut());
    }
}
