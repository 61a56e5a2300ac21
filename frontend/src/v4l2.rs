//! A V4L2 camera (`/dev/videoN`) as a frame source, behind the `v4l2` cargo
//! feature: why this exists is that a drone's companion computer sees its
//! camera through Video4Linux2, and the front-end must read it without any
//! library the README's set-up would have to install. It speaks the kernel's
//! ioctl interface directly (structures as in `linux/videodev2.h`, 64-bit),
//! with memory-mapped buffers.
//!
//! It asks for 8-bit grey (`GREY`); a camera that offers only `YUYV` (most
//! USB cameras) is read through its luma. Each frame carries the kernel's
//! capture time, which is `CLOCK_MONOTONIC`: run the daemon with
//! `features.clock = "monotonic"` (TIMESYNC maps it onto the autopilot's
//! clock). Untested on hardware here: this machine has no camera.

use std::ffi::CString;
use std::path::{Path, PathBuf};

use crate::image::Gray;
use crate::source::{FrameSource, SourceError, FROZEN_AFTER};

const fn fourcc(c: &[u8; 4]) -> u32 {
    (c[0] as u32) | ((c[1] as u32) << 8) | ((c[2] as u32) << 16) | ((c[3] as u32) << 24)
}
const PIX_GREY: u32 = fourcc(b"GREY");
const PIX_YUYV: u32 = fourcc(b"YUYV");
const BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
const MEMORY_MMAP: u32 = 1;
const CAP_VIDEO_CAPTURE: u32 = 0x1;
const CAP_STREAMING: u32 = 0x0400_0000;
const FIELD_NONE: u32 = 1;
/// Buffers asked for.
const BUFFERS: u32 = 4;

/// `_IOC(dir, 'V', nr, size)`.
const fn ioc(dir: u64, nr: u64, size: usize) -> u64 {
    (dir << 30) | ((size as u64) << 16) | ((b'V' as u64) << 8) | nr
}
const READ: u64 = 2;
const WRITE: u64 = 1;

#[repr(C)]
struct Capability {
    driver: [u8; 16],
    card: [u8; 32],
    bus_info: [u8; 32],
    version: u32,
    capabilities: u32,
    device_caps: u32,
    reserved: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy)]
struct PixFormat {
    width: u32,
    height: u32,
    pixelformat: u32,
    field: u32,
    bytesperline: u32,
    sizeimage: u32,
    colorspace: u32,
    private: u32,
    flags: u32,
    enc: u32,
    quantization: u32,
    xfer_func: u32,
}

/// `struct v4l2_format`: its union is 200 bytes, aligned to 8.
#[repr(C)]
struct Format {
    kind: u32,
    _pad: u32,
    pix: PixFormat,
    _rest: [u8; 200 - std::mem::size_of::<PixFormat>()],
}

#[repr(C)]
struct RequestBuffers {
    count: u32,
    kind: u32,
    memory: u32,
    capabilities: u32,
    flags: u8,
    reserved: [u8; 3],
}

#[repr(C)]
#[derive(Clone, Copy)]
struct Buffer {
    index: u32,
    kind: u32,
    bytesused: u32,
    flags: u32,
    field: u32,
    _pad: u32,
    timestamp: libc::timeval,
    timecode: [u32; 4],
    sequence: u32,
    memory: u32,
    /// The union `m`: the mmap offset in its low 32 bits.
    m: u64,
    length: u32,
    reserved2: u32,
    request_fd: u32,
    _pad2: u32,
}

const VIDIOC_QUERYCAP: u64 = ioc(READ, 0, std::mem::size_of::<Capability>());
const VIDIOC_S_FMT: u64 = ioc(READ | WRITE, 5, std::mem::size_of::<Format>());
const VIDIOC_REQBUFS: u64 = ioc(READ | WRITE, 8, std::mem::size_of::<RequestBuffers>());
const VIDIOC_QUERYBUF: u64 = ioc(READ | WRITE, 9, std::mem::size_of::<Buffer>());
const VIDIOC_QBUF: u64 = ioc(READ | WRITE, 15, std::mem::size_of::<Buffer>());
const VIDIOC_DQBUF: u64 = ioc(READ | WRITE, 17, std::mem::size_of::<Buffer>());
const VIDIOC_STREAMON: u64 = ioc(WRITE, 18, std::mem::size_of::<libc::c_int>());
const VIDIOC_STREAMOFF: u64 = ioc(WRITE, 19, std::mem::size_of::<libc::c_int>());

/// An open, streaming V4L2 capture device.
pub struct V4l2Source {
    path: PathBuf,
    fd: libc::c_int,
    maps: Vec<(*mut libc::c_void, usize)>,
    width: usize,
    height: usize,
    bytes_per_line: usize,
    yuyv: bool,
}

// SAFETY: the mappings are owned by this source alone and only touched
// through `&mut self`.
unsafe impl Send for V4l2Source {}

impl V4l2Source {
    /// Opens `path`, asks for `width × height` grey at the driver's rate,
    /// maps its buffers and starts streaming.
    pub fn open(path: &Path, width: u32, height: u32) -> Result<Self, SourceError> {
        let fail = |what: String| SourceError::Device(path.to_path_buf(), what);
        let err = |what: &str| fail(format!("{what}: {}", std::io::Error::last_os_error()));
        let c_path = CString::new(path.as_os_str().as_encoded_bytes()).map_err(|_| fail("a NUL in the path".into()))?;
        // SAFETY: a valid C string; the descriptor is closed in Drop.
        let fd = unsafe { libc::open(c_path.as_ptr(), libc::O_RDWR) };
        if fd < 0 {
            return Err(err("open"));
        }
        let mut src = Self {
            path: path.to_path_buf(),
            fd,
            maps: Vec::new(),
            width: 0,
            height: 0,
            bytes_per_line: 0,
            yuyv: false,
        };
        // SAFETY (all ioctls below): each is given a structure of the size
        // its request number encodes, laid out as linux/videodev2.h's.
        let mut cap: Capability = unsafe { std::mem::zeroed() };
        if unsafe { libc::ioctl(fd, VIDIOC_QUERYCAP as _, &mut cap) } < 0 {
            return Err(err("not a V4L2 device (VIDIOC_QUERYCAP)"));
        }
        let caps = if cap.device_caps != 0 {
            cap.device_caps
        } else {
            cap.capabilities
        };
        if caps & CAP_VIDEO_CAPTURE == 0 || caps & CAP_STREAMING == 0 {
            return Err(fail("the device cannot capture video by streaming".into()));
        }
        let mut fmt: Format = unsafe { std::mem::zeroed() };
        fmt.kind = BUF_TYPE_VIDEO_CAPTURE;
        fmt.pix.width = width;
        fmt.pix.height = height;
        fmt.pix.pixelformat = PIX_GREY;
        fmt.pix.field = FIELD_NONE;
        if unsafe { libc::ioctl(fd, VIDIOC_S_FMT as _, &mut fmt) } < 0 {
            return Err(err("VIDIOC_S_FMT"));
        }
        src.yuyv = match fmt.pix.pixelformat {
            PIX_GREY => false,
            PIX_YUYV => true,
            other => {
                return Err(fail(format!(
                    "the camera offers pixel format {:?}, neither GREY nor YUYV",
                    other.to_le_bytes().map(char::from)
                )))
            }
        };
        (src.width, src.height) = (fmt.pix.width as usize, fmt.pix.height as usize);
        if (src.width, src.height) != (width as usize, height as usize) {
            return Err(SourceError::Size {
                path: path.to_path_buf(),
                got_w: fmt.pix.width,
                got_h: fmt.pix.height,
                want_w: width as usize,
                want_h: height as usize,
            });
        }
        let min_line = src.width * if src.yuyv { 2 } else { 1 };
        src.bytes_per_line = (fmt.pix.bytesperline as usize).max(min_line);
        let mut req = RequestBuffers {
            count: BUFFERS,
            kind: BUF_TYPE_VIDEO_CAPTURE,
            memory: MEMORY_MMAP,
            capabilities: 0,
            flags: 0,
            reserved: [0; 3],
        };
        if unsafe { libc::ioctl(fd, VIDIOC_REQBUFS as _, &mut req) } < 0 || req.count == 0 {
            return Err(err("VIDIOC_REQBUFS"));
        }
        for index in 0..req.count {
            let mut b = src.buffer(index);
            if unsafe { libc::ioctl(fd, VIDIOC_QUERYBUF as _, &mut b) } < 0 {
                return Err(err("VIDIOC_QUERYBUF"));
            }
            let len = b.length as usize;
            // SAFETY: maps the driver's buffer `index` at the offset it gave.
            let ptr = unsafe {
                libc::mmap(
                    std::ptr::null_mut(),
                    len,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_SHARED,
                    fd,
                    (b.m & 0xFFFF_FFFF) as libc::off_t,
                )
            };
            if ptr == libc::MAP_FAILED {
                return Err(err("mmap"));
            }
            src.maps.push((ptr, len));
            if unsafe { libc::ioctl(fd, VIDIOC_QBUF as _, &mut b) } < 0 {
                return Err(err("VIDIOC_QBUF"));
            }
        }
        let mut kind = BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        if unsafe { libc::ioctl(fd, VIDIOC_STREAMON as _, &mut kind) } < 0 {
            return Err(err("VIDIOC_STREAMON"));
        }
        Ok(src)
    }

    fn buffer(&self, index: u32) -> Buffer {
        // SAFETY: all-zero is a valid v4l2_buffer.
        let mut b: Buffer = unsafe { std::mem::zeroed() };
        b.index = index;
        b.kind = BUF_TYPE_VIDEO_CAPTURE;
        b.memory = MEMORY_MMAP;
        b
    }
}

impl FrameSource for V4l2Source {
    fn next_frame(&mut self, img: &mut Gray) -> Result<Option<u64>, SourceError> {
        let mut b = self.buffer(0);
        let fail = |what: String| SourceError::Device(self.path.clone(), what);
        // A camera that captures nothing for FROZEN_AFTER is lost (the
        // caller opens it again), not waited for for ever.
        let mut pfd = libc::pollfd {
            fd: self.fd,
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        let ready = unsafe { libc::poll(&mut pfd, 1, FROZEN_AFTER.as_millis() as libc::c_int) };
        if ready == 0 {
            return Err(SourceError::Frozen(self.path.clone(), FROZEN_AFTER.as_secs_f64()));
        }
        if ready < 0 || pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 {
            return Err(fail(format!(
                "poll: the device is gone ({})",
                std::io::Error::last_os_error()
            )));
        }
        // SAFETY: as in `open`; a frame is ready.
        if unsafe { libc::ioctl(self.fd, VIDIOC_DQBUF as _, &mut b) } < 0 {
            return Err(fail(format!("VIDIOC_DQBUF: {}", std::io::Error::last_os_error())));
        }
        let Some(&(ptr, len)) = self.maps.get(b.index as usize) else {
            return Err(fail(format!("the driver returned buffer {}, unknown", b.index)));
        };
        // SAFETY: the mapping is `len` bytes, and the driver hands it to us
        // until it is queued again below.
        let bytes = unsafe { std::slice::from_raw_parts(ptr as *const u8, len) };
        let (w, h, step) = (self.width, self.height, if self.yuyv { 2 } else { 1 });
        img.width = w;
        img.height = h;
        img.px.clear();
        for y in 0..h {
            let row = &bytes[(y * self.bytes_per_line).min(len)..];
            img.px
                .extend((0..w).map(|x| row.get(x * step).map_or(0.0, |&v| f32::from(v))));
        }
        let t_us = b.timestamp.tv_sec as u64 * 1_000_000 + b.timestamp.tv_usec as u64;
        // SAFETY: gives the buffer back to the driver.
        if unsafe { libc::ioctl(self.fd, VIDIOC_QBUF as _, &mut b) } < 0 {
            return Err(fail(format!("VIDIOC_QBUF: {}", std::io::Error::last_os_error())));
        }
        Ok(Some(t_us))
    }
}

impl Drop for V4l2Source {
    fn drop(&mut self) {
        let mut kind = BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        // SAFETY: stops streaming, unmaps what was mapped, closes the fd.
        unsafe {
            libc::ioctl(self.fd, VIDIOC_STREAMOFF as _, &mut kind);
            for &(ptr, len) in &self.maps {
                libc::munmap(ptr, len);
            }
            libc::close(self.fd);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The structures have the kernel's sizes (64-bit), which the request
    /// numbers encode, and the request numbers are the kernel's.
    #[test]
    fn layouts_and_request_numbers_match_videodev2() {
        assert_eq!(std::mem::size_of::<Capability>(), 104);
        assert_eq!(std::mem::size_of::<Format>(), 208);
        assert_eq!(std::mem::size_of::<RequestBuffers>(), 20);
        assert_eq!(std::mem::size_of::<Buffer>(), 88);
        assert_eq!(VIDIOC_QUERYCAP, 0x8068_5600);
        assert_eq!(VIDIOC_S_FMT, 0xC0D0_5605);
        assert_eq!(VIDIOC_REQBUFS, 0xC014_5608);
        assert_eq!(VIDIOC_QUERYBUF, 0xC058_5609);
        assert_eq!(VIDIOC_QBUF, 0xC058_560F);
        assert_eq!(VIDIOC_DQBUF, 0xC058_5611);
        assert_eq!(VIDIOC_STREAMON, 0x4004_5612);
    }

    #[test]
    fn a_missing_device_is_a_clear_error() {
        let e = V4l2Source::open(Path::new("/dev/video-none-here"), 752, 480)
            .err()
            .expect("no such device");
        assert!(e.to_string().contains("/dev/video-none-here"), "{e}");
    }
}
