//! Instance, device selection, queue and allocator.

use super::{Error, Result};
use ash::{ext, vk};
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};
use std::ffi::{c_void, CStr, CString};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// How to open a device.
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Index or case-insensitive name substring; `None` picks the best device.
    pub device: Option<String>,
    /// Enable the Khronos validation layer when it is installed.
    pub validation: bool,
    /// How the trace kernels read; `None` picks by driver ([`Reads::for_driver`]).
    pub reads: Option<Reads>,
}

/// How the trace kernels read the scene and the guides' tables. Images are
/// the same either way, bit for bit; only the speed differs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Reads {
    /// Uniform texel buffers.
    Texel,
    /// Storage buffers.
    Storage,
}

impl Reads {
    /// As `--reads` spells it.
    pub fn name(self) -> &'static str {
        match self {
            Reads::Texel => "texel",
            Reads::Storage => "storage",
        }
    }

    /// The faster for a driver, as measured (`qtrace bench --speed`, 256×256):
    /// Mesa 22.3's llvmpipe fetches a texel with one gather but reads a
    /// storage buffer lane by lane (texel reads halved its trace pass);
    /// Mesa 25.0's inlines storage reads and calls a slower texel fetch, so
    /// there storage reads made `pt` 1.5–2.4× and `pt --nee` 1.2–1.8× as
    /// fast (docs/notebook.md, "Mesa versions"). Versions between were not measured
    /// and keep texel reads, as do other drivers.
    pub fn for_driver(driver: vk::DriverId, driver_info: &str) -> Self {
        // lavapipe's driverVersion is 1 whatever the release; its driver info
        // reads "Mesa 25.0.7-2~bpo12+1 (LLVM 15.0.6)".
        let mesa_major = driver_info
            .strip_prefix("Mesa ")
            .and_then(|v| v.split('.').next())
            .and_then(|v| v.parse::<u32>().ok());
        if driver == vk::DriverId::MESA_LLVMPIPE && mesa_major.is_some_and(|m| m >= 25) {
            Reads::Storage
        } else {
            Reads::Texel
        }
    }
}

/// What qtrace needs to know about a physical device.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceInfo {
    pub index: usize,
    pub name: String,
    pub kind: String,
    pub api_version: String,
    pub driver: String,
    pub float_atomics: bool,
    pub int64_atomics: bool,
    pub timestamps: bool,
    pub timestamp_period_ns: f32,
    pub max_storage_buffer_range: u64,
    /// Texels a uniform texel buffer view may span (16 bytes each here).
    pub max_texel_buffer_elements: u64,
    pub max_shared_memory: u32,
    pub max_workgroup_count: [u32; 3],
    pub subgroup_size: u32,
    /// Subgroup arithmetic (subgroupAdd) in compute shaders: the accumulate
    /// pass totals its stats with it.
    pub subgroup_arithmetic: bool,
    /// Subgroup ballot and vote in compute shaders: the trace kernel's lanes
    /// claim their paths with them.
    pub subgroup_ballot: bool,
    /// How the trace kernels read: the driver's choice, or the one asked for.
    pub reads: Reads,
    /// A CPU device that reads host memory in place
    /// (VK_EXT_external_memory_host): the alignment an imported range needs.
    #[serde(skip)]
    pub host_import_alignment: Option<u64>,
    #[serde(skip)]
    rank: u32,
    #[serde(skip)]
    queue_family: Option<u32>,
}

/// The one Vulkan context: entry, instance, device, queue and allocator.
pub struct GpuContext {
    _entry: ash::Entry,
    pub(super) instance: ash::Instance,
    pub(super) device: ash::Device,
    pub(super) queue: vk::Queue,
    pub(super) allocator: ManuallyDrop<Mutex<Allocator>>,
    pub(super) debug_utils: Option<ext::debug_utils::Device>,
    /// Present where `DeviceInfo::host_import_alignment` is.
    pub(super) external_memory_host: Option<ext::external_memory_host::Device>,
    messenger: Option<(ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    validation_errors: Box<AtomicU32>,
    pub(super) submitter: Mutex<super::commands::Submitter>,
    info: DeviceInfo,
}

fn load_entry() -> Result<ash::Entry> {
    unsafe { ash::Entry::load() }.map_err(|e| Error::Loader(e.to_string()))
}

fn create_instance(entry: &ash::Entry, validation: bool) -> Result<(ash::Instance, bool, bool)> {
    let layers = unsafe { entry.enumerate_instance_layer_properties()? };
    let has_validation = validation
        && layers
            .iter()
            .any(|l| l.layer_name_as_c_str() == Ok(VALIDATION_LAYER));
    if validation && !has_validation {
        log::warn!("validation requested but VK_LAYER_KHRONOS_validation is not installed");
    }
    let extensions = unsafe { entry.enumerate_instance_extension_properties(None)? };
    let has_debug_utils = extensions
        .iter()
        .any(|e| e.extension_name_as_c_str() == Ok(ext::debug_utils::NAME));

    let app_name = CString::new("qtrace").unwrap();
    let app = vk::ApplicationInfo::default()
        .application_name(&app_name)
        .engine_name(&app_name)
        .api_version(vk::API_VERSION_1_2);
    let layer_ptrs: Vec<*const i8> = if has_validation {
        vec![VALIDATION_LAYER.as_ptr()]
    } else {
        vec![]
    };
    let mut ext_ptrs: Vec<*const i8> = if has_debug_utils {
        vec![ext::debug_utils::NAME.as_ptr()]
    } else {
        vec![]
    };
    // With validation, synchronisation validation too: lavapipe runs passes
    // in order and hides missing barriers that real GPUs would expose.
    let has_features = has_validation
        && unsafe { entry.enumerate_instance_extension_properties(Some(VALIDATION_LAYER))? }
            .iter()
            .any(|e| e.extension_name_as_c_str() == Ok(ext::validation_features::NAME));
    if has_features {
        ext_ptrs.push(ext::validation_features::NAME.as_ptr());
    } else if has_validation {
        log::warn!("the validation layer offers no VK_EXT_validation_features: no synchronisation validation");
    }
    let enabled = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
    let mut features = vk::ValidationFeaturesEXT::default().enabled_validation_features(&enabled);
    let mut info = vk::InstanceCreateInfo::default()
        .application_info(&app)
        .enabled_layer_names(&layer_ptrs)
        .enabled_extension_names(&ext_ptrs);
    if has_features {
        info = info.push_next(&mut features);
    }
    let instance = unsafe { entry.create_instance(&info, None) }.map_err(|e| match e {
        // The loader says this when it finds no driver at all.
        vk::Result::ERROR_INCOMPATIBLE_DRIVER | vk::Result::ERROR_INITIALIZATION_FAILED => {
            Error::NoDevice
        }
        other => Error::Vk(other),
    })?;
    Ok((instance, has_validation, has_debug_utils))
}

fn has_device_extension(instance: &ash::Instance, pd: vk::PhysicalDevice, name: &CStr) -> bool {
    unsafe { instance.enumerate_device_extension_properties(pd) }
        .map(|exts| exts.iter().any(|e| e.extension_name_as_c_str() == Ok(name)))
        .unwrap_or(false)
}

fn describe(instance: &ash::Instance, pd: vk::PhysicalDevice, index: usize) -> DeviceInfo {
    let mut driver = vk::PhysicalDeviceDriverProperties::default();
    let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
    let mut props2 = vk::PhysicalDeviceProperties2::default()
        .push_next(&mut driver)
        .push_next(&mut subgroup);
    unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
    let props = props2.properties;
    let driver_name = driver
        .driver_info_as_c_str()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let subgroup_size = subgroup.subgroup_size;
    let compute_subgroup = |ops: vk::SubgroupFeatureFlags| {
        subgroup
            .supported_stages
            .contains(vk::ShaderStageFlags::COMPUTE)
            && subgroup.supported_operations.contains(ops)
    };

    let has_float_ext = has_device_extension(instance, pd, ext::shader_atomic_float::NAME);
    let mut float_features = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default();
    let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
    let mut features2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut v12);
    if has_float_ext {
        features2 = features2.push_next(&mut float_features);
    }
    unsafe { instance.get_physical_device_features2(pd, &mut features2) };
    let int64_atomics = v12.shader_buffer_int64_atomics == vk::TRUE;
    let float_atomics =
        has_float_ext && float_features.shader_buffer_float32_atomic_add == vk::TRUE;

    let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
    let queue_family = families
        .iter()
        .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))
        .map(|i| i as u32);
    let timestamps = queue_family.is_some_and(|q| families[q as usize].timestamp_valid_bits > 0)
        && props.limits.timestamp_period > 0.0;

    let (kind, rank) = match props.device_type {
        vk::PhysicalDeviceType::DISCRETE_GPU => ("discrete GPU", 0),
        vk::PhysicalDeviceType::INTEGRATED_GPU => ("integrated GPU", 1),
        vk::PhysicalDeviceType::VIRTUAL_GPU => ("virtual GPU", 2),
        vk::PhysicalDeviceType::CPU => ("CPU", 3),
        _ => ("other", 4),
    };
    let v = props.api_version;
    let reads = Reads::for_driver(driver.driver_id, &driver_name);
    // On a CPU device, memory imported from the host is the same memory the
    // device would have copied it into: a large scene's tables need no copy.
    let host_import_alignment = (props.device_type == vk::PhysicalDeviceType::CPU
        && has_device_extension(instance, pd, ext::external_memory_host::NAME))
    .then(|| {
        let mut host = vk::PhysicalDeviceExternalMemoryHostPropertiesEXT::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default().push_next(&mut host);
        unsafe { instance.get_physical_device_properties2(pd, &mut props2) };
        host.min_imported_host_pointer_alignment
    })
    .filter(|&a| a > 0 && a.is_power_of_two());
    DeviceInfo {
        index,
        name: props
            .device_name_as_c_str()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        kind: kind.into(),
        api_version: format!(
            "{}.{}.{}",
            vk::api_version_major(v),
            vk::api_version_minor(v),
            vk::api_version_patch(v)
        ),
        driver: driver_name,
        float_atomics,
        int64_atomics,
        timestamps,
        timestamp_period_ns: props.limits.timestamp_period,
        max_storage_buffer_range: props.limits.max_storage_buffer_range as u64,
        max_texel_buffer_elements: props.limits.max_texel_buffer_elements as u64,
        max_shared_memory: props.limits.max_compute_shared_memory_size,
        max_workgroup_count: props.limits.max_compute_work_group_count,
        subgroup_size,
        subgroup_arithmetic: compute_subgroup(vk::SubgroupFeatureFlags::ARITHMETIC),
        subgroup_ballot: compute_subgroup(
            vk::SubgroupFeatureFlags::BALLOT | vk::SubgroupFeatureFlags::VOTE,
        ),
        reads,
        host_import_alignment,
        rank,
        queue_family,
    }
}

fn enumerate(instance: &ash::Instance) -> Result<Vec<(vk::PhysicalDevice, DeviceInfo)>> {
    let devices = unsafe { instance.enumerate_physical_devices() }.map_err(|e| match e {
        vk::Result::ERROR_INITIALIZATION_FAILED => Error::NoDevice,
        other => Error::Vk(other),
    })?;
    Ok(devices
        .into_iter()
        .enumerate()
        .map(|(i, pd)| (pd, describe(instance, pd, i)))
        .filter(|(_, info)| {
            let major_minor = info.api_version.split('.').take(2).collect::<Vec<_>>();
            let ok_version = major_minor
                .iter()
                .map(|s| s.parse::<u32>().unwrap_or(0))
                .collect::<Vec<_>>()
                >= vec![1, 2];
            ok_version && info.queue_family.is_some()
        })
        .collect())
}

/// Every usable Vulkan device (Vulkan 1.2 or later with a compute queue).
pub fn list_devices() -> Result<Vec<DeviceInfo>> {
    let entry = load_entry()?;
    let (instance, _, _) = create_instance(&entry, false)?;
    let result = enumerate(&instance).map(|v| v.into_iter().map(|(_, info)| info).collect());
    unsafe { instance.destroy_instance(None) };
    result
}

fn choose(
    devices: Vec<(vk::PhysicalDevice, DeviceInfo)>,
    selector: Option<&str>,
) -> Result<(vk::PhysicalDevice, DeviceInfo)> {
    if devices.is_empty() {
        return Err(Error::NoDevice);
    }
    match selector {
        None => devices
            .into_iter()
            .min_by_key(|(_, info)| (info.rank, info.index))
            .ok_or(Error::NoDevice),
        Some(sel) => {
            let wanted = sel.trim();
            let by_index = wanted.parse::<usize>().ok();
            devices
                .into_iter()
                .find(|(_, info)| match by_index {
                    Some(i) => info.index == i,
                    None => info.name.to_lowercase().contains(&wanted.to_lowercase()),
                })
                .ok_or_else(|| Error::NoMatchingDevice(sel.to_string()))
        }
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    let message = if data.is_null() {
        String::new()
    } else {
        (*data)
            .message_as_c_str()
            .map(|m| m.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        if !user.is_null() {
            (*(user as *const AtomicU32)).fetch_add(1, Ordering::Relaxed);
        }
        log::error!("Vulkan validation: {message}");
    } else if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING) {
        log::warn!("Vulkan validation: {message}");
    }
    vk::FALSE
}

impl GpuContext {
    /// Open the chosen device (see [`ContextOptions`]); `QTRACE_DEVICE` is read by the CLI.
    pub fn new(options: &ContextOptions) -> Result<Arc<Self>> {
        let entry = load_entry()?;
        let (instance, validation, has_debug_utils) = create_instance(&entry, options.validation)?;
        match Self::open(
            &entry,
            instance.clone(),
            validation,
            has_debug_utils,
            options,
        ) {
            Ok(ctx) => Ok(Arc::new(ctx)),
            Err(e) => {
                // `entry` (the loaded library) must outlive this call.
                unsafe { instance.destroy_instance(None) };
                Err(e)
            }
        }
    }

    fn open(
        entry: &ash::Entry,
        instance: ash::Instance,
        validation: bool,
        has_debug_utils: bool,
        options: &ContextOptions,
    ) -> Result<Self> {
        let (physical, mut info) = choose(enumerate(&instance)?, options.device.as_deref())?;
        info.reads = options.reads.unwrap_or(info.reads);
        let queue_family = info.queue_family.ok_or(Error::NoDevice)?;

        let priorities = [1.0f32];
        let queue_info = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family)
            .queue_priorities(&priorities)];
        let mut extensions: Vec<*const i8> = Vec::new();
        let mut float_features = vk::PhysicalDeviceShaderAtomicFloatFeaturesEXT::default()
            .shader_buffer_float32_atomic_add(info.float_atomics)
            .shader_buffer_float32_atomics(info.float_atomics);
        if info.float_atomics {
            extensions.push(ext::shader_atomic_float::NAME.as_ptr());
        }
        if info.host_import_alignment.is_some() {
            extensions.push(ext::external_memory_host::NAME.as_ptr());
        }
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default()
            .shader_buffer_int64_atomics(info.int64_atomics);
        let features = vk::PhysicalDeviceFeatures::default().shader_int64(info.int64_atomics);
        let mut device_info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .enabled_extension_names(&extensions)
            .enabled_features(&features)
            .push_next(&mut v12);
        if info.float_atomics {
            device_info = device_info.push_next(&mut float_features);
        }
        let device = unsafe { instance.create_device(physical, &device_info, None)? };
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let debug_utils =
            has_debug_utils.then(|| ext::debug_utils::Device::new(&instance, &device));
        let external_memory_host = info
            .host_import_alignment
            .map(|_| ext::external_memory_host::Device::new(&instance, &device));

        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: false,
            allocation_sizes: Default::default(),
        });
        let allocator = match allocator {
            Ok(a) => a,
            Err(e) => {
                unsafe { device.destroy_device(None) };
                return Err(e.into());
            }
        };
        let submitter = match super::commands::Submitter::new(&device, queue_family) {
            Ok(s) => s,
            Err(e) => {
                drop(allocator);
                unsafe { device.destroy_device(None) };
                return Err(e);
            }
        };
        let validation_errors = Box::new(AtomicU32::new(0));
        // Created last, so that no failure above leaves it behind.
        let messenger = if validation && has_debug_utils {
            let loader = ext::debug_utils::Instance::new(entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                        | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(&*validation_errors as *const AtomicU32 as *mut c_void);
            match unsafe { loader.create_debug_utils_messenger(&info, None) } {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    log::warn!("validation messages unavailable: {e}");
                    None
                }
            }
        } else {
            None
        };

        log::info!(
            "using Vulkan device {} ({}, {})",
            info.name,
            info.kind,
            info.driver
        );
        Ok(Self {
            _entry: entry.clone(),
            instance,
            device,
            queue,
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            debug_utils,
            external_memory_host,
            messenger,
            validation_errors,
            submitter: Mutex::new(submitter),
            info,
        })
    }

    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Validation-layer errors reported so far (0 when validation is off).
    pub fn validation_errors(&self) -> u32 {
        self.validation_errors.load(Ordering::Relaxed)
    }

    /// Whether the Khronos validation layer is active on this context.
    pub fn validation_enabled(&self) -> bool {
        self.messenger.is_some()
    }

    pub(super) fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        if let (Some(du), Ok(cname)) = (&self.debug_utils, CString::new(name)) {
            let info = vk::DebugUtilsObjectNameInfoEXT::default()
                .object_handle(handle)
                .object_name(&cname);
            // Naming is a debugging aid; a failure here is harmless.
            let _ = unsafe { du.set_debug_utils_object_name(&info) };
        }
    }
}

impl Drop for GpuContext {
    fn drop(&mut self) {
        unsafe {
            let _ = self.device.device_wait_idle();
            self.submitter
                .get_mut()
                .unwrap_or_else(|e| e.into_inner())
                .destroy(&self.device);
            ManuallyDrop::drop(&mut self.allocator);
            self.device.destroy_device(None);
            if let Some((loader, m)) = self.messenger.take() {
                loader.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}
