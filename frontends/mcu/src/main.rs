//! Cortex-M3 firmware: renders one shaded 128×128 frame of a 64³ `.swv` volume streamed
//! slice by slice from flash, reports the instructions the frame took, writes the image
//! to the host as a binary PPM through semihosting, and exits with a status.
//!
//! Everything is static: the stream source holds one slice, the workspace the
//! intermediate image, row buffers and shade table. Sizes are fixed at compile time for a
//! 64³ volume and a 128-pixel-wide image.
#![no_std]
#![no_main]

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::{debug, hprintln};
use shearwarp_core::composite;
use shearwarp_core::io::SliceReader;
use shearwarp_core::render::{render, StaticWorkspace};
use shearwarp_core::swv::{self, StreamSource};
use shearwarp_core::view::{self, Camera};
use shearwarp_core::warp::FrameBuffer;

mod no_panic;

/// The volume, in flash.
static VOLUME: &[u8] = include_bytes!(env!("SHEARWARP_SWV"));

const DIMS: [usize; 3] = [64, 64, 64];
const W: usize = 128;
const H: usize = 128;
const CAP: (usize, usize, usize) = swv::worst_case_capacity(DIMS);
const PIX: usize = view::max_intermediate_pixels(DIMS);
const ROW: usize = composite::row_buffer_len(64);

type Source = StreamSource<SliceReader<'static>, { CAP.0 }, { CAP.1 }, { CAP.2 }>;
type Work = StaticWorkspace<PIX, ROW, W>;

/// The view rendered (the README's, scaled to 128²).
const CAMERA: Camera = Camera {
    rotate_x: -70.0,
    rotate_y: -35.0,
    width: W,
    height: H,
};

static WRAPS: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

/// SysTick ticks since start (24-bit counter plus wrap count).
fn ticks(syst: &cortex_m::peripheral::SYST) -> u64 {
    loop {
        let w0 = WRAPS.load(Ordering::Relaxed);
        let cur = cortex_m::peripheral::SYST::get_current();
        let w1 = WRAPS.load(Ordering::Relaxed);
        if w0 == w1 {
            let _ = syst;
            return w0 as u64 * (1 << 24) + (0x00FF_FFFF - cur) as u64;
        }
    }
}

fn run() -> Result<(), &'static str> {
    let mut cp = cortex_m::Peripherals::take().ok_or("peripherals taken")?;
    let opened =
        StreamSource::open(SliceReader::new(VOLUME)).map_err(|_| "cannot open the .swv volume")?;
    let source: &'static mut Source =
        cortex_m::singleton!(: Source = opened).ok_or("source singleton")?;
    let work: &'static mut Work = cortex_m::singleton!(: Work = Work::new()).ok_or("work")?;
    let frame: &'static mut [[u8; 4]; W * H] =
        cortex_m::singleton!(: [[u8; 4]; W * H] = [[0; 4]; W * H]).ok_or("frame")?;

    let look = source.header().look.clone();
    let settings = look.settings();

    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00FF_FFFF);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();
    // Writing the current value zeroes it; the first clock reloads it without a wrap.
    while cortex_m::peripheral::SYST::get_current() == 0 {}
    // Per-frame setup alone (factorization, shading and opacity tables), for the report,
    // twice: the first also tabulates the specular power, which the shading table keeps
    // for later frames with the same material (as the frame below). Each for a view
    // turned from the frame's, as in an animation: a table already filled for a view's
    // lights is not filled again, which would leave the fill out of both figures.
    let mut setup = [0u64; 2];
    for (i, s) in setup.iter_mut().enumerate() {
        let turned = Camera {
            rotate_y: CAMERA.rotate_y + 10.0 * (i + 1) as f64,
            ..CAMERA
        };
        let s0 = ticks(&cp.SYST);
        let ws = work.workspace();
        let grid = shearwarp_core::source::SliceSource::grid(source);
        shearwarp_core::render::Frame::new(&grid, &turned, &settings, ws.shade, None)
            .map_err(|_| "frame setup failed")?;
        *s = ticks(&cp.SYST) - s0;
    }
    let t0 = ticks(&cp.SYST);
    {
        let mut sink = FrameBuffer {
            width: W,
            pixels: &mut frame[..],
        };
        render(source, &CAMERA, &settings, &mut work.workspace(), &mut sink)
            .map_err(|_| "render failed")?;
    }
    let t1 = ticks(&cp.SYST);
    cp.SYST.disable_counter();
    // mps2-an385 clocks the core (and SysTick) at 25 MHz: 40 ns per tick; with
    // `-icount shift=0` one instruction takes 1 ns of virtual time.
    let instructions = (t1 - t0) * 40;
    hprintln!(
        "frame {}x{}: {} systick ticks, {} instructions (icount shift=0), of which setup {} (the first frame's setup, with the specular power table: {}), workspace {} bytes, stream buffers {} bytes",
        W,
        H,
        t1 - t0,
        instructions,
        setup[1] * 40,
        setup[0] * 40,
        Work::BYTES,
        core::mem::size_of::<Source>()
    );

    let out = HostFile::create("mcu_frame.ppm\0")?;
    out.write_all(b"P6\n128 128\n255\n")?;
    for row in frame.chunks(W) {
        let mut rgb = [0u8; 3 * W];
        for (o, p) in rgb.chunks_exact_mut(3).zip(row) {
            o.copy_from_slice(&p[..3]);
        }
        out.write_all(&rgb)?;
    }
    out.close();
    Ok(())
}

/// A file on the host, through semihosting (the crate's file API is private, so the three
/// calls are made directly).
struct HostFile(usize);

impl HostFile {
    /// `name` must end in a NUL byte.
    fn create(name: &str) -> Result<Self, &'static str> {
        if !name.ends_with('\0') {
            return Err("host file name must be NUL-terminated");
        }
        // SAFETY: SYS_OPEN reads `name.len() - 1` bytes from a live, NUL-terminated
        // string; the debugger (QEMU) does not write guest memory for this call.
        let fd = unsafe {
            cortex_m_semihosting::syscall!(
                OPEN,
                name.as_ptr(),
                cortex_m_semihosting::nr::open::W_TRUNC_BINARY,
                name.len() - 1
            )
        };
        if fd as isize == -1 {
            return Err("cannot create the output file on the host");
        }
        Ok(HostFile(fd))
    }

    fn write_all(&self, buf: &[u8]) -> Result<(), &'static str> {
        // SAFETY: SYS_WRITE reads `buf.len()` bytes from a live slice.
        let left =
            unsafe { cortex_m_semihosting::syscall!(WRITE, self.0, buf.as_ptr(), buf.len()) };
        if left == 0 {
            Ok(())
        } else {
            Err("short write to the host file")
        }
    }

    fn close(self) {
        // SAFETY: closes a handle this struct owns; no memory is passed.
        unsafe {
            cortex_m_semihosting::syscall!(CLOSE, self.0);
        }
    }
}

#[entry]
fn main() -> ! {
    match run() {
        Ok(()) => debug::exit(debug::EXIT_SUCCESS),
        Err(e) => {
            hprintln!("error: {}", e);
            debug::exit(debug::EXIT_FAILURE)
        }
    }
    loop {
        cortex_m::asm::wfi();
    }
}
