//! Buffers allocated through gpu-allocator, freed on `Drop`.

use super::{Error, GpuContext, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// A named storage buffer. The constructor says where its memory lives.
pub struct Buffer {
    ctx: Arc<GpuContext>,
    pub(super) raw: vk::Buffer,
    allocation: Option<Allocation>,
    /// Host memory the device reads in place, and what keeps it alive.
    imported: Option<(vk::DeviceMemory, Arc<dyn std::any::Any + Send + Sync>)>,
    size: u64,
    /// Bytes allocated: `size` rounded up to whole 16-byte texels.
    capacity: u64,
    name: String,
}

/// The largest staging buffer an upload uses.
pub const STAGING_BYTES: u64 = 64 << 20;

/// Fault injection for tests: with `QTRACE_FAIL_ALLOCATION=N` in the
/// environment, the N-th buffer allocation of the process (from 0) fails as
/// a device out of memory would, so tests can check that every allocation
/// failure ends in an error, not a crash.
fn injected_failure() -> bool {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNT: AtomicU64 = AtomicU64::new(0);
    let Some(n) = std::env::var("QTRACE_FAIL_ALLOCATION")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
    else {
        return false;
    };
    COUNT.fetch_add(1, Ordering::Relaxed) == n
}

impl Buffer {
    fn new(
        ctx: &Arc<GpuContext>,
        name: &str,
        size: u64,
        location: MemoryLocation,
        usage: vk::BufferUsageFlags,
    ) -> Result<Self> {
        let failed = |e: gpu_allocator::AllocationError| Error::BufferAlloc {
            name: name.into(),
            size,
            message: e.to_string(),
        };
        if injected_failure() {
            return Err(failed(gpu_allocator::AllocationError::OutOfMemory));
        }
        // Vulkan forbids empty buffers; an empty list still needs a binding.
        let size = size.max(16);
        // Whole 16-byte texels, so a texel view reaches the last element.
        let capacity = size.next_multiple_of(16);
        let info = vk::BufferCreateInfo::default()
            .size(capacity)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let device = &ctx.device;
        let raw = unsafe { device.create_buffer(&info, None)? };
        let requirements = unsafe { device.get_buffer_memory_requirements(raw) };
        let allocation = ctx
            .allocator
            .lock()
            .unwrap()
            .allocate(&AllocationCreateDesc {
                name,
                requirements,
                location,
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            });
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                unsafe { device.destroy_buffer(raw, None) };
                return Err(failed(e));
            }
        };
        if let Err(e) =
            unsafe { device.bind_buffer_memory(raw, allocation.memory(), allocation.offset()) }
        {
            let _ = ctx.allocator.lock().unwrap().free(allocation);
            unsafe { device.destroy_buffer(raw, None) };
            return Err(e.into());
        }
        ctx.set_name(raw, name);
        Ok(Self {
            ctx: ctx.clone(),
            raw,
            allocation: Some(allocation),
            imported: None,
            size,
            capacity,
            name: name.into(),
        })
    }

    /// Device-local memory, filled and read through transfers; shaders see it
    /// as a storage buffer or a uniform texel buffer.
    pub fn gpu_only(ctx: &Arc<GpuContext>, name: &str, size: u64) -> Result<Self> {
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST;
        Self::new(ctx, name, size, MemoryLocation::GpuOnly, usage)
    }

    /// Host-visible memory the host writes and shaders read.
    pub fn upload(ctx: &Arc<GpuContext>, name: &str, size: u64) -> Result<Self> {
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC;
        Self::new(ctx, name, size, MemoryLocation::CpuToGpu, usage)
    }

    /// Host-visible memory shaders or transfers write and the host reads.
    pub fn readback(ctx: &Arc<GpuContext>, name: &str, size: u64) -> Result<Self> {
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST;
        Self::new(ctx, name, size, MemoryLocation::GpuToCpu, usage)
    }

    /// A buffer the shaders read straight from `data`, host memory that
    /// `owner` keeps alive and unchanged for as long as the buffer lives:
    /// where the device is a CPU that imports host memory, and `data` lies
    /// as the import needs (whole 16-byte texels, 16-byte aligned). `None`
    /// elsewhere: then copy it into a buffer of the device's own.
    pub fn import_host<T: bytemuck::Pod>(
        ctx: &Arc<GpuContext>,
        name: &str,
        data: &[T],
        owner: Arc<dyn std::any::Any + Send + Sync>,
    ) -> Result<Option<Self>> {
        let (Some(page), Some(ext)) = (
            ctx.info().host_import_alignment,
            ctx.external_memory_host.as_ref(),
        ) else {
            return Ok(None);
        };
        let size = std::mem::size_of_val(data) as u64;
        let address = data.as_ptr() as u64;
        if size == 0 || size % 16 != 0 || address % 16 != 0 {
            return Ok(None);
        }
        // The whole pages around the data: an allocation's pages are its
        // process's, so the bytes around it may be mapped too (never written).
        let start = address & !(page - 1);
        let end = (address + size).next_multiple_of(page);
        let offset = address - start;
        let handle = vk::ExternalMemoryHandleTypeFlags::HOST_ALLOCATION_EXT;
        let device = &ctx.device;
        let mut external = vk::ExternalMemoryBufferCreateInfo::default().handle_types(handle);
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(
                vk::BufferUsageFlags::STORAGE_BUFFER
                    | vk::BufferUsageFlags::UNIFORM_TEXEL_BUFFER
                    | vk::BufferUsageFlags::TRANSFER_SRC,
            )
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .push_next(&mut external);
        let raw = unsafe { device.create_buffer(&info, None)? };
        let requirements = unsafe { device.get_buffer_memory_requirements(raw) };
        let mut host = vk::MemoryHostPointerPropertiesEXT::default();
        // SAFETY: `start` is the page holding `data`, mapped in this process.
        let queried = unsafe {
            (ext.fp().get_memory_host_pointer_properties_ext)(
                device.handle(),
                handle,
                start as *const std::ffi::c_void,
                &mut host,
            )
        };
        let types = host.memory_type_bits & requirements.memory_type_bits;
        log::debug!(
            "import of '{name}': {queried:?}, memory types {types:#b}, offset {offset}, alignment {}",
            requirements.alignment
        );
        if queried != vk::Result::SUCCESS || types == 0 || offset % requirements.alignment != 0 {
            unsafe { device.destroy_buffer(raw, None) };
            return Ok(None);
        }
        let mut import = vk::ImportMemoryHostPointerInfoEXT::default()
            .handle_type(handle)
            .host_pointer(start as *mut std::ffi::c_void);
        let allocate = vk::MemoryAllocateInfo::default()
            .allocation_size(end - start)
            .memory_type_index(types.trailing_zeros())
            .push_next(&mut import);
        let memory = match unsafe { device.allocate_memory(&allocate, None) } {
            Ok(m) => m,
            Err(e) => {
                // The driver would not take this memory: a copy will do.
                log::debug!("import of '{name}' refused: {e}");
                unsafe { device.destroy_buffer(raw, None) };
                return Ok(None);
            }
        };
        if let Err(e) = unsafe { device.bind_buffer_memory(raw, memory, offset) } {
            unsafe {
                device.destroy_buffer(raw, None);
                device.free_memory(memory, None);
            }
            return Err(e.into());
        }
        ctx.set_name(raw, name);
        Ok(Some(Self {
            ctx: ctx.clone(),
            raw,
            allocation: None,
            imported: Some((memory, owner)),
            size,
            capacity: size,
            name: name.into(),
        }))
    }

    /// A device-local buffer holding `data`, copied through a staging buffer.
    pub fn gpu_only_with<T: bytemuck::Pod>(
        ctx: &Arc<GpuContext>,
        name: &str,
        data: &[T],
    ) -> Result<Self> {
        let buffer = Self::gpu_only(ctx, name, std::mem::size_of_val(data) as u64)?;
        buffer.overwrite(data)?;
        Ok(buffer)
    }

    /// Overwrites the start of a device-local buffer with `data`: written
    /// in place where the host sees its memory (a CPU device's), else
    /// [`Buffer::stage`]d.
    pub fn overwrite<T: bytemuck::Pod>(&self, data: &[T]) -> Result<()> {
        if self.mapped().is_some() {
            self.write(data);
            return Ok(());
        }
        self.stage(data)
    }

    /// Overwrites the start of the buffer with `data` copied through a
    /// staging buffer of at most [`STAGING_BYTES`], a piece at a time: a
    /// large scene's tables need no second copy of themselves.
    ///
    /// Panics on a buffer imported from the host: its memory is its owner's.
    pub fn stage<T: bytemuck::Pod>(&self, data: &[T]) -> Result<()> {
        assert!(
            self.imported.is_none(),
            "'{}' reads host memory it does not own",
            self.name
        );
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.is_empty() {
            return Ok(());
        }
        let staging = Self::upload(
            &self.ctx,
            &format!("{} (staging)", self.name),
            (bytes.len() as u64).min(STAGING_BYTES),
        )?;
        for (k, piece) in bytes.chunks(STAGING_BYTES as usize).enumerate() {
            staging.write(piece);
            let offset = k as u64 * STAGING_BYTES;
            self.ctx.submit(None, |rec| {
                rec.copy_region(&staging, self, offset, piece.len() as u64)
            })?;
        }
        Ok(())
    }

    /// The whole contents of a device-local buffer, copied through a readback buffer.
    pub fn download<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        if self.mapped().is_some() {
            return Ok(self.read());
        }
        let staging = Self::readback(&self.ctx, &format!("{} (readback)", self.name), self.size)?;
        self.ctx.submit(None, |rec| rec.copy(self, &staging))?;
        Ok(staging.read())
    }

    fn mapped(&self) -> Option<std::ptr::NonNull<std::ffi::c_void>> {
        self.allocation.as_ref().and_then(|a| a.mapped_ptr())
    }

    /// Writes `data` at the start of a host-visible buffer.
    ///
    /// Panics if the buffer is not host-visible or too small: both are programming errors.
    pub fn write<T: bytemuck::Pod>(&self, data: &[T]) {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        assert!(
            bytes.len() as u64 <= self.size,
            "write past the end of '{}'",
            self.name
        );
        let ptr = self
            .mapped()
            .expect("write to a buffer that is not host-visible");
        // SAFETY: the mapping covers `size` bytes and no GPU work uses the buffer
        // while the host writes (every submit waits for its fence).
        unsafe {
            std::ptr::copy_nonoverlapping(bytes.as_ptr(), ptr.as_ptr() as *mut u8, bytes.len())
        };
    }

    /// The contents of a host-visible buffer as `T`s (trailing bytes ignored).
    pub fn read<T: bytemuck::Pod>(&self) -> Vec<T> {
        let ptr = self
            .mapped()
            .expect("read from a buffer that is not host-visible");
        let count = self.size as usize / std::mem::size_of::<T>();
        let mut out = vec![T::zeroed(); count];
        // SAFETY: as in `write`; `out` holds exactly `count * size_of::<T>()` bytes.
        unsafe {
            std::ptr::copy_nonoverlapping(
                ptr.as_ptr() as *const u8,
                out.as_mut_ptr() as *mut u8,
                count * std::mem::size_of::<T>(),
            )
        };
        out
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// Bytes a texel view may cover (whole texels past `size`).
    pub(super) fn capacity(&self) -> u64 {
        self.capacity
    }

    pub fn size(&self) -> u64 {
        self.size
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        if let Some(allocation) = self.allocation.take() {
            let _ = self.ctx.allocator.lock().unwrap().free(allocation);
        }
        unsafe { self.ctx.device.destroy_buffer(self.raw, None) };
        if let Some((memory, _owner)) = self.imported.take() {
            // The buffer is gone, so the memory may go; the owner after it.
            unsafe { self.ctx.device.free_memory(memory, None) };
        }
    }
}
