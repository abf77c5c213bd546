//! The FMI 2.0 co-simulation C API: every `fmi2*` function that `FMPy` and other masters resolve,
//! exported unmangled from the shared library.
//!
//! Owns only the boundary: checks and converts pointers, delegates to [`crate::instance`], logs
//! what comes back through the master's callback, and catches every panic so none crosses into
//! C. The only `unsafe` code of the FMU is here, each block with its `SAFETY` reason. Functions
//! the model description declares unsupported return `fmi2Error` (`fmi2Discard` for a status
//! that is not available) and say why in the log.
#![allow(
    unsafe_code,
    reason = "the FMI C API hands over raw pointers; this module is the FMU's only unsafe code"
)]
#![allow(non_snake_case, reason = "the FMI standard names these functions")]

use std::ffi::{CStr, CString, c_char, c_int, c_uint, c_void};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::ptr;

use armtwin_core::fmi::LogCategory;

use crate::instance::{self, CallError, Instance, InstantiateError};

/// `fmi2Status`.
pub type Fmi2Status = c_int;
/// `fmi2OK`.
pub const FMI2_OK: Fmi2Status = 0;
/// `fmi2Discard`.
pub const FMI2_DISCARD: Fmi2Status = 2;
/// `fmi2Error`.
pub const FMI2_ERROR: Fmi2Status = 3;
/// `fmi2Fatal`.
pub const FMI2_FATAL: Fmi2Status = 4;

/// `fmi2Component`: a pointer to this library's [`Component`].
pub type Fmi2Component = *mut c_void;
/// `fmi2ValueReference`.
pub type Fmi2ValueReference = c_uint;
/// `fmi2Boolean`.
pub type Fmi2Boolean = c_int;
/// `fmi2String`.
pub type Fmi2String = *const c_char;
/// `fmi2FMUstate`.
pub type Fmi2FmuState = *mut c_void;

/// `fmi2CallbackLogger`: `void logger(env, instanceName, status, category, message, ...)`, the
/// message a `printf` format.
pub type Fmi2CallbackLogger =
    unsafe extern "C" fn(*mut c_void, Fmi2String, Fmi2Status, Fmi2String, Fmi2String, ...);

/// `fmi2CallbackFunctions`, as the master passes it to `fmi2Instantiate`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct Fmi2CallbackFunctions {
    /// The logger; may be null (nothing is then logged).
    pub logger: Option<Fmi2CallbackLogger>,
    /// `allocateMemory`: unused (`canNotUseMemoryManagementFunctions="true"`).
    pub allocate_memory: Option<unsafe extern "C" fn(usize, usize) -> *mut c_void>,
    /// `freeMemory`: unused.
    pub free_memory: Option<unsafe extern "C" fn(*mut c_void)>,
    /// `stepFinished`: unused (`fmi2DoStep` completes synchronously).
    pub step_finished: Option<unsafe extern "C" fn(*mut c_void, Fmi2Status)>,
    /// Handed back to the logger.
    pub component_environment: *mut c_void,
}

/// The master's logger with what every message carries.
#[derive(Debug, Clone)]
struct Logger {
    callback: Option<Fmi2CallbackLogger>,
    environment: *mut c_void,
    instance_name: CString,
}

impl Logger {
    fn log(&self, status: Fmi2Status, category: LogCategory, message: &str) {
        let Some(callback) = self.callback else {
            return;
        };
        // FMI messages escape '#' (it introduces `#r12#` value references); a C string cannot
        // hold NUL.
        let message =
            CString::new(message.replace('#', "##").replace('\0', "\\0")).unwrap_or_default();
        let category = match category {
            LogCategory::StatusError => c"logStatusError",
            LogCategory::StatusDiscard => c"logStatusDiscard",
            LogCategory::Calls => c"logCalls",
        };
        // SAFETY: `callback` is the master's logger from `fmi2CallbackFunctions`, called with its
        // own environment pointer and NUL-terminated strings that outlive the call. The message
        // travels as the argument of a constant "%s" format, so nothing in it is read as a
        // format directive.
        unsafe {
            callback(
                self.environment,
                self.instance_name.as_ptr(),
                status,
                category.as_ptr(),
                c"%s".as_ptr(),
                message.as_ptr(),
            );
        }
    }
}

/// What an `fmi2Component` points to: one instance and its master's logger.
#[derive(Debug)]
pub struct Component {
    instance: Instance,
    logger: Logger,
}

/// How a call that did not fail ends.
enum Reply {
    /// `fmi2OK`, with a message for the `logCalls` category.
    Ok(Option<String>),
    /// `fmi2Discard`, with the reason.
    Discard(String),
}

/// Runs `body` on the instance behind `c`: null `c` is an error (with no logger to tell);
/// failures are logged and move the instance to its error state; a panic is caught, logged and
/// reported as `fmi2Fatal`.
fn with_instance(
    c: Fmi2Component,
    function: &'static str,
    body: impl FnOnce(&mut Instance) -> Result<Reply, CallError>,
) -> Fmi2Status {
    let component = c.cast::<Component>();
    if component.is_null() {
        return FMI2_ERROR;
    }
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: a non-null `fmi2Component` is the pointer `fmi2Instantiate` returned (from
        // `Box::into_raw`) and not yet freed; FMI forbids concurrent calls on one instance, so
        // this is the only reference for the duration of the call.
        let component = unsafe { &mut *component };
        let (status, message) = match body(&mut component.instance) {
            Ok(Reply::Ok(message)) => (
                FMI2_OK,
                message
                    .filter(|_| component.instance.logs(LogCategory::Calls))
                    .map(|m| (LogCategory::Calls, m)),
            ),
            Ok(Reply::Discard(reason)) => {
                (FMI2_DISCARD, Some((LogCategory::StatusDiscard, reason)))
            }
            Err(error) => (
                FMI2_ERROR,
                Some((LogCategory::StatusError, error.to_string())),
            ),
        };
        (status, message, component.logger.clone())
    }));
    match outcome {
        Ok((status, message, logger)) => {
            if let Some((category, message)) = message {
                logger.log(status, category, &message);
            }
            status
        }
        Err(panic) => {
            // SAFETY: as above; the closure that held the other reference has unwound.
            let component = unsafe { &mut *component };
            let error = component.instance.reject(CallError::Internal {
                function,
                message: panic_message(&*panic).to_owned(),
            });
            component
                .logger
                .log(FMI2_FATAL, LogCategory::StatusError, &error.to_string());
            FMI2_FATAL
        }
    }
}

fn panic_message(panic: &(dyn std::any::Any + Send)) -> &str {
    panic
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| panic.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("panic")
}

/// The `len` elements at `pointer` (any pointer when `len` is 0); a null pointer is rejected by
/// `instance`.
///
/// # Safety
/// When `len > 0` and `pointer` is not null, `pointer` must be valid for reading `len` elements
/// for `'a`.
unsafe fn slice<'a, T>(
    instance: &mut Instance,
    pointer: *const T,
    len: usize,
    function: &'static str,
    argument: &'static str,
) -> Result<&'a [T], CallError> {
    if len == 0 {
        return Ok(&[]);
    }
    if pointer.is_null() || len > isize::MAX.unsigned_abs() / size_of::<T>().max(1) {
        return Err(instance.reject(CallError::NullPointer { function, argument }));
    }
    // SAFETY: non-null, a sane length, and the caller guarantees `len` readable elements.
    Ok(unsafe { std::slice::from_raw_parts(pointer, len) })
}

/// The `len` writable elements at `pointer` (any pointer when `len` is 0); a null pointer is
/// rejected by `instance`.
///
/// # Safety
/// When `len > 0` and `pointer` is not null, `pointer` must be valid for writing `len` elements
/// for `'a`, and not aliased.
unsafe fn slice_mut<'a, T>(
    instance: &mut Instance,
    pointer: *mut T,
    len: usize,
    function: &'static str,
    argument: &'static str,
) -> Result<&'a mut [T], CallError> {
    if len == 0 {
        return Ok(&mut []);
    }
    if pointer.is_null() || len > isize::MAX.unsigned_abs() / size_of::<T>().max(1) {
        return Err(instance.reject(CallError::NullPointer { function, argument }));
    }
    // SAFETY: non-null, a sane length, and the caller guarantees `len` writable, unaliased
    // elements.
    Ok(unsafe { std::slice::from_raw_parts_mut(pointer, len) })
}

/// Writes `value` through `pointer`, an out-argument; a null pointer is rejected by `instance`.
///
/// # Safety
/// A non-null `pointer` must be valid for writing one `T`.
unsafe fn write_out<T>(
    instance: &mut Instance,
    pointer: *mut T,
    value: T,
    function: &'static str,
    argument: &'static str,
) -> Result<(), CallError> {
    if pointer.is_null() {
        return Err(instance.reject(CallError::NullPointer { function, argument }));
    }
    // SAFETY: non-null, and the caller guarantees it is writable.
    unsafe { pointer.write(value) };
    Ok(())
}

/// Why a C string argument cannot be read.
enum TextError {
    Null,
    NotUtf8,
}

/// The UTF-8 text of a C string.
///
/// # Safety
/// A non-null `pointer` must point to a NUL-terminated string valid for `'a`.
unsafe fn text<'a>(pointer: *const c_char) -> Result<&'a str, TextError> {
    if pointer.is_null() {
        return Err(TextError::Null);
    }
    // SAFETY: non-null and NUL-terminated by the caller's guarantee.
    unsafe { CStr::from_ptr(pointer) }
        .to_str()
        .map_err(|_| TextError::NotUtf8)
}

/// `fmi2GetTypesPlatform`: `"default"`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2GetTypesPlatform() -> Fmi2String {
    c"default".as_ptr()
}

/// `fmi2GetVersion`: `"2.0"`.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2GetVersion() -> Fmi2String {
    c"2.0".as_ptr()
}

/// `fmi2Instantiate`: a co-simulation instance of the robot in the resources, or null (logged).
///
/// # Safety
/// The string arguments must be null or NUL-terminated; `functions` must be null or point to an
/// `fmi2CallbackFunctions` whose logger, if set, is callable as FMI specifies.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2Instantiate(
    instance_name: Fmi2String,
    fmu_type: c_int,
    fmu_guid: Fmi2String,
    fmu_resource_location: Fmi2String,
    functions: *const Fmi2CallbackFunctions,
    _visible: Fmi2Boolean,
    logging_on: Fmi2Boolean,
) -> Fmi2Component {
    if functions.is_null() {
        return ptr::null_mut();
    }
    // SAFETY: non-null, and the caller guarantees it points to the callback struct; it is copied
    // here, so the master need not keep it alive.
    let functions = unsafe { functions.read() };
    // SAFETY: null or NUL-terminated, by the caller's guarantee.
    let name = unsafe { text(instance_name) };
    let logger = Logger {
        callback: functions.logger,
        environment: functions.component_environment,
        instance_name: CString::new(name.unwrap_or_default()).unwrap_or_default(),
    };
    let outcome = catch_unwind(AssertUnwindSafe(
        || -> Result<Instance, InstantiateError> {
            let read = |pointer: Fmi2String, argument: &'static str| {
                // SAFETY: null or NUL-terminated, by the caller's guarantee.
                unsafe { text(pointer) }.map_err(|problem| match problem {
                    TextError::Null => InstantiateError::NullPointer { argument },
                    TextError::NotUtf8 => InstantiateError::Encoding { argument },
                })
            };
            let name = read(instance_name, "instanceName")?;
            let guid = read(fmu_guid, "fmuGUID")?;
            let location = read(fmu_resource_location, "fmuResourceLocation")?;
            instance::instantiate(name, fmu_type, guid, location, logging_on != 0)
        },
    ));
    match outcome {
        Ok(Ok(instance)) => {
            if instance.logs(LogCategory::Calls) {
                logger.log(
                    FMI2_OK,
                    LogCategory::Calls,
                    &format!("fmi2Instantiate: {}", instance.describe()),
                );
            }
            Box::into_raw(Box::new(Component { instance, logger })).cast()
        }
        Ok(Err(error)) => {
            logger.log(FMI2_ERROR, LogCategory::StatusError, &error.to_string());
            ptr::null_mut()
        }
        Err(panic) => {
            logger.log(
                FMI2_FATAL,
                LogCategory::StatusError,
                &format!(
                    "fmi2Instantiate: internal error: {}",
                    panic_message(&*panic)
                ),
            );
            ptr::null_mut()
        }
    }
}

/// `fmi2FreeInstance`: frees the instance; null is ignored.
///
/// # Safety
/// `c` must be null or a pointer `fmi2Instantiate` returned that was not freed yet; it must not
/// be used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2FreeInstance(c: Fmi2Component) {
    if c.is_null() {
        return;
    }
    // SAFETY: `c` came from `Box::into_raw` in `fmi2Instantiate` and is freed once, by the
    // caller's guarantee.
    let component = unsafe { Box::from_raw(c.cast::<Component>()) };
    // Dropping plain data cannot panic; catch it anyway so nothing unwinds into C.
    let _ = catch_unwind(AssertUnwindSafe(move || drop(component)));
}

/// `fmi2SetDebugLogging`: debug logging on or off, for the named categories (all when none).
///
/// # Safety
/// `c` as for every function: null or a live instance. `categories` must be null or hold
/// `n_categories` NUL-terminated strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetDebugLogging(
    c: Fmi2Component,
    logging_on: Fmi2Boolean,
    n_categories: usize,
    categories: *const Fmi2String,
) -> Fmi2Status {
    const FUNCTION: &str = "fmi2SetDebugLogging";
    with_instance(c, FUNCTION, |instance| {
        // SAFETY: the caller guarantees `n_categories` readable pointers.
        let pointers =
            unsafe { slice(instance, categories, n_categories, FUNCTION, "categories") }?;
        let names = pointers
            .iter()
            // SAFETY: each is null or NUL-terminated, by the caller's guarantee.
            .map(|&pointer| unsafe { text(pointer) })
            .collect::<Result<Vec<_>, _>>()
            .map_err(|_| {
                instance.reject(CallError::Encoding {
                    function: FUNCTION,
                    argument: "categories",
                })
            })?;
        instance.set_debug_logging(logging_on != 0, &names)?;
        Ok(Reply::Ok(Some(format!(
            "{FUNCTION}: loggingOn={logging_on}, categories {names:?}"
        ))))
    })
}

/// `fmi2SetupExperiment`: the start time.
///
/// # Safety
/// `c` must be null or a live instance.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetupExperiment(
    c: Fmi2Component,
    _tolerance_defined: Fmi2Boolean,
    _tolerance: f64,
    start_time: f64,
    _stop_time_defined: Fmi2Boolean,
    _stop_time: f64,
) -> Fmi2Status {
    with_instance(c, "fmi2SetupExperiment", |instance| {
        instance.setup_experiment(start_time)?;
        Ok(Reply::Ok(Some(format!(
            "fmi2SetupExperiment: startTime={start_time}"
        ))))
    })
}

macro_rules! lifecycle {
    ($(#[$doc:meta])* $name:ident => $method:ident) => {
        $(#[$doc])*
        ///
        /// # Safety
        /// `c` must be null or a live instance.
        #[unsafe(no_mangle)]
        pub unsafe extern "C" fn $name(c: Fmi2Component) -> Fmi2Status {
            with_instance(c, stringify!($name), |instance| {
                instance.$method()?;
                Ok(Reply::Ok(Some(format!(
                    "{}: now {}",
                    stringify!($name),
                    instance.state()
                ))))
            })
        }
    };
}

lifecycle!(
    /// `fmi2EnterInitializationMode`.
    fmi2EnterInitializationMode => enter_initialization_mode
);
lifecycle!(
    /// `fmi2ExitInitializationMode`.
    fmi2ExitInitializationMode => exit_initialization_mode
);
lifecycle!(
    /// `fmi2Terminate`.
    fmi2Terminate => terminate
);

/// `fmi2Reset`: back to the state after instantiation.
///
/// # Safety
/// `c` must be null or a live instance.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2Reset(c: Fmi2Component) -> Fmi2Status {
    with_instance(c, "fmi2Reset", |instance| {
        instance.reset();
        Ok(Reply::Ok(Some("fmi2Reset: now instantiated".to_owned())))
    })
}

/// `fmi2GetReal`.
///
/// # Safety
/// `c` must be null or a live instance; `vr` and `value` null or valid for `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetReal(
    c: Fmi2Component,
    vr: *const Fmi2ValueReference,
    nvr: usize,
    value: *mut f64,
) -> Fmi2Status {
    const FUNCTION: &str = "fmi2GetReal";
    with_instance(c, FUNCTION, |instance| {
        // SAFETY: the caller guarantees `nvr` readable value references.
        let vrs = unsafe { slice(instance, vr, nvr, FUNCTION, "vr") }?;
        // SAFETY: the caller guarantees `nvr` writable values.
        let values = unsafe { slice_mut(instance, value, nvr, FUNCTION, "value") }?;
        instance.get_real(vrs, values)?;
        Ok(Reply::Ok(None))
    })
}

/// `fmi2SetReal`.
///
/// # Safety
/// `c` must be null or a live instance; `vr` and `value` null or valid for `nvr` elements.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetReal(
    c: Fmi2Component,
    vr: *const Fmi2ValueReference,
    nvr: usize,
    value: *const f64,
) -> Fmi2Status {
    const FUNCTION: &str = "fmi2SetReal";
    with_instance(c, FUNCTION, |instance| {
        // SAFETY: the caller guarantees `nvr` readable value references.
        let vrs = unsafe { slice(instance, vr, nvr, FUNCTION, "vr") }?;
        // SAFETY: the caller guarantees `nvr` readable values.
        let values = unsafe { slice(instance, value, nvr, FUNCTION, "value") }?;
        instance.set_real(vrs, values)?;
        Ok(Reply::Ok(None))
    })
}

/// Get or set of a type this FMU has no variables of: checks the pointers (no value is read or
/// written), then every value reference is unknown.
///
/// # Safety
/// `vr` null or valid for `nvr` elements.
unsafe fn untyped(
    c: Fmi2Component,
    function: &'static str,
    type_name: &'static str,
    setter: bool,
    vr: *const Fmi2ValueReference,
    nvr: usize,
    value_is_null: bool,
) -> Fmi2Status {
    with_instance(c, function, |instance| {
        // SAFETY: the caller guarantees `nvr` readable value references.
        let vrs = unsafe { slice(instance, vr, nvr, function, "vr") }?;
        if nvr > 0 && value_is_null {
            return Err(instance.reject(CallError::NullPointer {
                function,
                argument: "value",
            }));
        }
        instance.untyped(function, type_name, setter, vrs)?;
        Ok(Reply::Ok(None))
    })
}

macro_rules! untyped_accessor {
    ($name:ident, $type_name:literal, $setter:literal, $value:ty) => {
        #[doc = concat!("`", stringify!($name), "`: this FMU has no ", $type_name, " variables.")]
        ///
        /// # Safety
        /// `c` must be null or a live instance; `vr` and `value` null or valid for `nvr`
        /// elements.
        #[unsafe(no_mangle)]
        pub unsafe extern "C" fn $name(
            c: Fmi2Component,
            vr: *const Fmi2ValueReference,
            nvr: usize,
            value: $value,
        ) -> Fmi2Status {
            // SAFETY: forwarded from this function's own contract.
            unsafe {
                untyped(
                    c,
                    stringify!($name),
                    $type_name,
                    $setter,
                    vr,
                    nvr,
                    value.is_null(),
                )
            }
        }
    };
}

untyped_accessor!(fmi2GetInteger, "Integer", false, *mut c_int);
untyped_accessor!(fmi2GetBoolean, "Boolean", false, *mut Fmi2Boolean);
untyped_accessor!(fmi2GetString, "String", false, *mut Fmi2String);
untyped_accessor!(fmi2SetInteger, "Integer", true, *const c_int);
untyped_accessor!(fmi2SetBoolean, "Boolean", true, *const Fmi2Boolean);
untyped_accessor!(fmi2SetString, "String", true, *const Fmi2String);

/// `fmi2DoStep`: advances time; the outputs already follow the inputs.
///
/// # Safety
/// `c` must be null or a live instance.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2DoStep(
    c: Fmi2Component,
    current_communication_point: f64,
    communication_step_size: f64,
    _no_set_fmu_state_prior_to_current_point: Fmi2Boolean,
) -> Fmi2Status {
    with_instance(c, "fmi2DoStep", |instance| {
        instance.do_step(current_communication_point, communication_step_size)?;
        Ok(Reply::Ok(Some(format!(
            "fmi2DoStep: {current_communication_point} + {communication_step_size}"
        ))))
    })
}

macro_rules! unsupported {
    ($name:ident, $reason:literal, ($($argument:ident: $type:ty),*)) => {
        #[doc = concat!("`", stringify!($name), "`: not supported (", $reason, "); returns `fmi2Error`.")]
        ///
        /// # Safety
        /// `c` must be null or a live instance; no other argument is read.
        #[unsafe(no_mangle)]
        pub unsafe extern "C" fn $name(c: Fmi2Component, $(_: $type),*) -> Fmi2Status {
            with_instance(c, stringify!($name), |instance| {
                Err(instance.unsupported(stringify!($name), $reason))
            })
        }
    };
}

unsupported!(fmi2GetFMUstate, "canGetAndSetFMUstate=\"false\"", (state: *mut Fmi2FmuState));
unsupported!(fmi2SetFMUstate, "canGetAndSetFMUstate=\"false\"", (state: Fmi2FmuState));
unsupported!(fmi2FreeFMUstate, "canGetAndSetFMUstate=\"false\"", (state: *mut Fmi2FmuState));
unsupported!(
    fmi2SerializedFMUstateSize,
    "canSerializeFMUstate=\"false\"",
    (state: Fmi2FmuState, size: *mut usize)
);
unsupported!(
    fmi2SerializeFMUstate,
    "canSerializeFMUstate=\"false\"",
    (state: Fmi2FmuState, bytes: *mut c_char, size: usize)
);
unsupported!(
    fmi2DeSerializeFMUstate,
    "canSerializeFMUstate=\"false\"",
    (bytes: *const c_char, size: usize, state: *mut Fmi2FmuState)
);
unsupported!(
    fmi2GetDirectionalDerivative,
    "providesDirectionalDerivative=\"false\"",
    (
        unknown_vr: *const Fmi2ValueReference,
        n_unknown: usize,
        known_vr: *const Fmi2ValueReference,
        n_known: usize,
        delta_known: *const f64,
        delta_unknown: *mut f64
    )
);
unsupported!(
    fmi2SetRealInputDerivatives,
    "canInterpolateInputs=\"false\"",
    (vr: *const Fmi2ValueReference, nvr: usize, order: *const c_int, value: *const f64)
);
unsupported!(
    fmi2GetRealOutputDerivatives,
    "maxOutputDerivativeOrder=\"0\"",
    (vr: *const Fmi2ValueReference, nvr: usize, order: *const c_int, value: *mut f64)
);
unsupported!(
    fmi2CancelStep,
    "canRunAsynchronuously=\"false\": no step is ever in progress",
    ()
);

fn not_available(function: &str, kind: c_int) -> Reply {
    Reply::Discard(format!(
        "{function}: status kind {kind} is not available (fmi2DoStep completes at once and never \
         returns fmi2Pending or fmi2Discard)"
    ))
}

/// `fmi2GetStatus`: never available (`fmi2Discard`): no step is ever pending.
///
/// # Safety
/// `c` must be null or a live instance; `value` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetStatus(
    c: Fmi2Component,
    kind: c_int,
    value: *mut Fmi2Status,
) -> Fmi2Status {
    // SAFETY: forwarded from this function's own contract.
    unsafe { unavailable_status(c, "fmi2GetStatus", kind, value) }
}

/// `fmi2GetIntegerStatus`: never available (`fmi2Discard`).
///
/// # Safety
/// `c` must be null or a live instance; `value` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetIntegerStatus(
    c: Fmi2Component,
    kind: c_int,
    value: *mut c_int,
) -> Fmi2Status {
    // SAFETY: forwarded from this function's own contract.
    unsafe { unavailable_status(c, "fmi2GetIntegerStatus", kind, value) }
}

/// `fmi2GetStringStatus`: never available (`fmi2Discard`).
///
/// # Safety
/// `c` must be null or a live instance; `value` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetStringStatus(
    c: Fmi2Component,
    kind: c_int,
    value: *mut Fmi2String,
) -> Fmi2Status {
    // SAFETY: forwarded from this function's own contract.
    unsafe { unavailable_status(c, "fmi2GetStringStatus", kind, value) }
}

/// # Safety
/// `value` null or writable (it is only checked, never written).
unsafe fn unavailable_status<T>(
    c: Fmi2Component,
    function: &'static str,
    kind: c_int,
    value: *mut T,
) -> Fmi2Status {
    with_instance(c, function, |instance| {
        if value.is_null() {
            return Err(instance.reject(CallError::NullPointer {
                function,
                argument: "value",
            }));
        }
        instance.unavailable_status(function)?;
        Ok(not_available(function, kind))
    })
}

/// `fmi2GetRealStatus`: `fmi2LastSuccessfulTime` is the time where the last step ended; other
/// kinds are not available (`fmi2Discard`).
///
/// # Safety
/// `c` must be null or a live instance; `value` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetRealStatus(
    c: Fmi2Component,
    kind: c_int,
    value: *mut f64,
) -> Fmi2Status {
    const FUNCTION: &str = "fmi2GetRealStatus";
    with_instance(c, FUNCTION, |instance| {
        match instance.real_status(kind)? {
            Some(time_s) => {
                // SAFETY: null or writable, by the caller's guarantee.
                unsafe { write_out(instance, value, time_s, FUNCTION, "value") }?;
                Ok(Reply::Ok(None))
            }
            None => Ok(not_available(FUNCTION, kind)),
        }
    })
}

/// `fmi2GetBooleanStatus`: `fmi2Terminated` is false (this FMU never ends a simulation); other
/// kinds are not available (`fmi2Discard`).
///
/// # Safety
/// `c` must be null or a live instance; `value` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetBooleanStatus(
    c: Fmi2Component,
    kind: c_int,
    value: *mut Fmi2Boolean,
) -> Fmi2Status {
    const FUNCTION: &str = "fmi2GetBooleanStatus";
    with_instance(c, FUNCTION, |instance| {
        match instance.boolean_status(kind)? {
            Some(flag) => {
                let flag = Fmi2Boolean::from(flag);
                // SAFETY: null or writable, by the caller's guarantee.
                unsafe { write_out(instance, value, flag, FUNCTION, "value") }?;
                Ok(Reply::Ok(None))
            }
            None => Ok(not_available(FUNCTION, kind)),
        }
    })
}
