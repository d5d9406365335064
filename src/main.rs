//! The RTIC application of the odometry unit (STM32F401): thin wiring around `odo_core`.
//!
//! Data path of one sample: a TIM5 compare match is the sample instant (the grid comes
//! from the PPS discipline, `odo_core::timing::pps`); the TIM5 interrupt (priority 4)
//! snapshots both encoder counters as its first action, then the fault lines, labels the
//! instant (`odo_core::timing::catch_up`, which also merges the points a stall passed over)
//! and hands a [`app::RawSample`] to the processing task through a lock-free queue. The processing task (priority 2) extends the
//! counters to 64 bits, applies index pulses, integrates, tags GNSS time, builds the pose
//! record and queues its frame for the host link whole, or drops it and counts it. The
//! USART2 interrupt (priority 3) moves queued bytes to the UART and received bytes to the
//! command task (priority 1), which parses and executes command lines, saves settings to
//! flash and queues the replies. Index (TIM2/TIM3 capture, priority 4) and NMEA (USART1,
//! priority 3) interrupts only take the latched value and queue it. Only the processing and
//! command tasks log (defmt-rtt in non-blocking mode: a full RTT buffer drops log frames,
//! it never stalls the firmware).
//!
//! Pins, peripherals and clocks: `src/board/mod.rs` and `docs/HARDWARE.md`.
#![cfg_attr(target_os = "none", no_std, no_main)]
#![cfg_attr(target_os = "none", deny(clippy::unwrap_used, clippy::expect_used))]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "odo-unit is firmware for the STM32F401: build it with the default target \
         (thumbv7em-none-eabihf); host tools live in odoctl"
    );
}

#[cfg(target_os = "none")]
mod board;

#[cfg(all(target_os = "none", not(feature = "qemu")))]
use defmt_rtt as _;
#[cfg(all(target_os = "none", feature = "qemu"))]
use defmt_semihosting as _;
#[cfg(target_os = "none")]
use panic_probe as _;

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use crate::board::{
        self,
        encoders::{IndexCapture, Snapshot, LEFT_BITS, RIGHT_BITS},
        flash::SettingsFlash,
        sampler::Sampler,
        serial::{GnssUart, HostUart, RxErrors, TxRing},
        Acquisition, ClockSource, GnssRx, Led,
    };
    use heapless::spsc::{Consumer, Producer, Queue};
    use odo_core::odometry::{
        ChassisParams, CounterExtender, IndexRefs, Integrator, Pose, WheelCounts,
    };
    use odo_core::protocol::command::{self, Action, LineAssembler, Reply};
    use odo_core::protocol::{
        self, CommandReply, DeviceInfo, GnssTime, Message, PoseRecord, SettingsSource, Status,
        StatusFlags, WheelStatus, PROTOCOL_VERSION,
    };
    use odo_core::settings::{store::SettingsStore, Settings};
    use odo_core::timing::index::DEFAULT_TOLERANCE;
    use odo_core::timing::{
        Discipline, DisciplineConfig, IndexCheck, IndexTracker, LineBuffer, NmeaError, PpsEvent,
        PpsStats, Sample, SyncMode, SyncState, TimeTagPps, TimeTagger,
    };
    use rtic::Mutex;
    use stm32f4xx_hal::pac::Interrupt;
    use stm32f4xx_hal::prelude::*;
    use stm32f4xx_hal::watchdog::IndependentWatchdog;

    /// Host link transmit buffer, bytes.
    const TX_BUF: usize = 4096;
    /// Transmit space a pose record leaves free for command replies, bytes.
    const RECORD_RESERVE: usize = 1024;

    /// One sample, from the TIM5 interrupt to the processing task.
    #[derive(Clone, Copy)]
    pub struct RawSample {
        /// The schedule's sample.
        sample: Sample,
        /// Raw counters.
        counts: Snapshot,
        /// Fault lines (left, right).
        faults: (bool, bool),
        /// A PPS edge seen in this interrupt.
        pps: Option<(u64, PpsEvent)>,
        /// Discipline state and counters after this interrupt.
        state: SyncState,
        stats: PpsStats,
        /// Length of a second in use, ticks.
        period: u64,
        /// Index pulses of the simulated drive (QEMU build only; EXTI on the board).
        sim_index: [Option<u32>; 2],
        /// Cycles (instructions in QEMU) the sample interrupt took up to the hand-over.
        isr_cycles: u32,
        /// Grid points merged into this sample because the interrupt ran late (a stall).
        merged: u32,
        /// Timer ticks from the sample's grid point to the interrupt's counter reading.
        latency: u32,
        /// A PPS edge was lost to an over-capture before this sample.
        pps_overcapture: bool,
        /// Samples lost so far because the queue to the processing task was full.
        queue_lost: u32,
    }

    /// The host link's transmit side: the byte ring and the frame sequence number.
    pub struct Link {
        ring: TxRing<TX_BUF>,
        next_seq: u32,
    }

    /// Changes the command task asks the processing task to apply at the next sample.
    #[derive(Default)]
    pub struct Requests {
        settings: Option<Settings>,
        reset: Option<Pose>,
    }

    /// Where the settings in use came from and whether they differ from the stored ones
    /// (kept by the command task, reported by the heartbeat).
    #[derive(Clone, Copy)]
    pub struct StoreState {
        source: SettingsSource,
        dirty: bool,
    }

    /// What the processing task last knew, for `status`.
    #[derive(Clone, Copy, Default)]
    pub struct Live {
        samples: u32,
        dropped_total: u32,
        flags: StatusFlags,
        stats: PpsStats,
        period: u64,
        index_mismatches: [u32; 2],
        nmea_errors: u32,
        time_messages: u32,
        mcu_time_us: u64,
        /// Most cycles of one sample interrupt, and of processing one sample.
        isr_cycles_max: u32,
        process_cycles_max: u32,
        /// Cycles of the last sample interrupt and of processing the last sample.
        isr_cycles_last: u32,
        process_cycles_last: u32,
        /// Samples lost between the sample interrupt and the processing task (queue full).
        samples_lost: u32,
        /// Grid points merged into later samples (late sample interrupts: flash stalls).
        merged_samples: u32,
        /// Largest latency from a sample's grid point to the interrupt's counter reading,
        /// timer ticks.
        latency_max: u32,
        /// Index pulses lost to an over-capture (left, right).
        index_lost: [u32; 2],
        /// PPS edges lost to an over-capture.
        pps_overcaptures: u32,
        /// The wheels moved within the last second.
        moving: bool,
    }

    #[shared]
    struct Shared {
        acq: Acquisition,
        link: Link,
        requests: Requests,
        live: Live,
        host_errors: RxErrors,
        gnss_errors: RxErrors,
        store_state: StoreState,
    }

    #[local]
    struct Local {
        sampler: Sampler,
        samples_in: Producer<'static, RawSample>,
        samples_out: Consumer<'static, RawSample>,
        index_in_left: Producer<'static, IndexCapture>,
        index_in_right: Producer<'static, IndexCapture>,
        index_out_left: Consumer<'static, IndexCapture>,
        index_out_right: Consumer<'static, IndexCapture>,
        host: HostUart,
        host_rx_in: Producer<'static, u8>,
        host_rx_out: Consumer<'static, u8>,
        gnss: GnssRx,
        gnss_in: Producer<'static, u8>,
        gnss_out: Consumer<'static, u8>,
        cfg_in: Producer<'static, DisciplineConfig>,
        cfg_out: Consumer<'static, DisciplineConfig>,
        processor: Processor,
        commands: Commands,
        led: Led,
        watchdog: IndependentWatchdog,
    }

    /// The discipline configuration that `settings` ask for, with the PPS lock range of
    /// the clock running now.
    fn discipline_config(
        settings: &Settings,
        timer_hz: u32,
        clock: ClockSource,
    ) -> DisciplineConfig {
        let tolerance = board::clock_tolerance_ppm(board::clock_source(clock));
        let mut cfg = DisciplineConfig::for_clock(timer_hz, tolerance);
        cfg.rate_hz = settings.rate;
        cfg.mode = settings.mode;
        cfg
    }

    fn time_tag(settings: &Settings) -> TimeTagPps {
        settings.time_tag_pps
    }

    fn state_name(s: SyncState) -> &'static str {
        match s {
            SyncState::FreeRunning => "free-running",
            SyncState::Locked => "pps-locked",
            SyncState::Holdover => "holdover",
        }
    }

    #[init(local = [
        samples_q: Queue<RawSample, 32> = Queue::new(),
        index_left_q: Queue<IndexCapture, 16> = Queue::new(),
        index_right_q: Queue<IndexCapture, 16> = Queue::new(),
        host_rx_q: Queue<u8, 512> = Queue::new(),
        gnss_q: Queue<u8, 512> = Queue::new(),
        cfg_q: Queue<DisciplineConfig, 4> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        board::stack::paint();
        let dp = cx.device;
        let mut core = cx.core;
        board::start_cycle_counter(&mut core);
        // The watchdog first (it runs from the LSI): nothing after this can hang for good.
        let mut watchdog = IndependentWatchdog::new(dp.IWDG);
        watchdog.stop_on_debug(&dp.DBGMCU, true);
        watchdog.start(board::WATCHDOG_MS.millis());
        let (mut rcc, clock) = board::start_clocks(dp.RCC);
        let clocks = rcc.clocks;
        let timer_hz = board::timer_hz(&clocks);
        if clock == ClockSource::HsiFallback {
            defmt::error!("HSE did not start: running from the HSI (+-4 %)");
        }

        let pins = board::pins(dp.GPIOA, dp.GPIOB, dp.GPIOC, &mut rcc);

        // Settings: the newest valid record in flash, else the defaults.
        #[cfg(not(feature = "qemu"))]
        let flash = SettingsFlash::new(dp.FLASH);
        #[cfg(feature = "qemu")]
        let flash = SettingsFlash::new();
        let mut store = SettingsStore::new(flash);
        let loaded = store.load_or_defaults();
        let mut settings = loaded.settings;
        let mut cfg = discipline_config(&settings, timer_hz, clock);
        if cfg.validate().is_err() {
            defmt::error!("settings: rate/mode unusable by the sampler, using the defaults");
            settings = Settings::DEFAULT;
            cfg = discipline_config(&settings, timer_hz, clock);
        }
        match loaded.source {
            SettingsSource::Flash => defmt::info!(
                "settings loaded from flash, generation {}",
                loaded.generation
            ),
            SettingsSource::Defaults => {
                defmt::info!("settings: defaults (flash empty or unreadable)")
            }
        }

        #[cfg(not(feature = "qemu"))]
        let mut acq = Acquisition::new(
            board::encoders::Encoders::new(dp.TIM2, dp.TIM3, &mut rcc),
            pins.faults,
        );
        #[cfg(feature = "qemu")]
        let mut acq = Acquisition::new(pins.faults);

        let host = HostUart::new(dp.USART2, &mut rcc, clocks.pclk1().raw(), settings.baud);
        let gnss = GnssUart::new(dp.USART1, &mut rcc, clocks.pclk2().raw(), board::GNSS_BAUD);
        // QEMU: PPS captures and NMEA bytes from the simulated receiver (src/board/sim_gnss.rs).
        #[cfg(feature = "qemu")]
        let (gnss, gnss_sim) = board::sim_gnss::attach(gnss);

        let (samples_in, samples_out) = cx.local.samples_q.split();
        let (index_in_left, index_out_left) = cx.local.index_left_q.split();
        let (index_in_right, index_out_right) = cx.local.index_right_q.split();
        let (host_rx_in, host_rx_out) = cx.local.host_rx_q.split();
        let (gnss_in, gnss_out) = cx.local.gnss_q.split();
        let (cfg_in, cfg_out) = cx.local.cfg_q.split();

        let disc = match Discipline::new(cfg, 0) {
            Ok(d) => d,
            Err(_) => {
                defmt::error!("sampler configuration invalid: free-running at 50 Hz");
                let mut c =
                    DisciplineConfig::for_clock(timer_hz, board::clock_tolerance_ppm(clock));
                c.mode = SyncMode::Free;
                c.rate_hz = 50;
                cfg = c;
                match Discipline::new(c, 0) {
                    Ok(d) => d,
                    Err(_) => panic!("default sampler configuration rejected"),
                }
            }
        };
        #[cfg(not(feature = "qemu"))]
        let (sampler, s0) = Sampler::start(dp.TIM5, &mut rcc, disc);
        #[cfg(feature = "qemu")]
        let (sampler, s0) = Sampler::start(dp.TIM5, &mut rcc, disc, gnss_sim);
        // Sample 0 is now: snapshot it as the starting point of the integration.
        let first = RawSample {
            sample: s0,
            counts: acq.snapshot(s0.tick),
            faults: acq.faults(s0.tick),
            pps: None,
            state: sampler.discipline().state(),
            stats: sampler.discipline().stats(),
            period: sampler.discipline().period(),
            sim_index: [None, None],
            isr_cycles: 0,
            merged: 0,
            latency: 0,
            pps_overcapture: false,
            queue_lost: 0,
        };
        let mut samples_in = samples_in;
        let _ = samples_in.enqueue(first);
        rtic::pend(Interrupt::SPI2);

        defmt::info!(
            "odo-unit {} booted: timer {} Hz, {} Hz {}",
            env!("CARGO_PKG_VERSION"),
            timer_hz,
            cfg.rate_hz,
            if cfg.mode == SyncMode::Pps {
                "pps"
            } else {
                "free"
            }
        );

        let processor = Processor::new(&settings, timer_hz);
        let commands = Commands {
            assembler: LineAssembler::new(),
            settings,
            store,
            source: loaded.source,
            dirty: false,
            timer_hz,
            clock,
        };
        (
            Shared {
                acq,
                link: Link {
                    ring: TxRing::new(),
                    next_seq: 0,
                },
                requests: Requests::default(),
                live: Live::default(),
                host_errors: RxErrors::default(),
                gnss_errors: RxErrors::default(),
                store_state: StoreState {
                    source: loaded.source,
                    dirty: false,
                },
            },
            Local {
                sampler,
                samples_in,
                samples_out,
                index_in_left,
                index_in_right,
                index_out_left,
                index_out_right,
                host,
                host_rx_in,
                host_rx_out,
                gnss,
                gnss_in,
                gnss_out,
                cfg_in,
                cfg_out,
                processor,
                commands,
                led: pins.led,
                watchdog,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// The sample instant (TIM5 compare) and the PPS capture (TIM5 CH1): snapshot and hand
    /// on. No logging here: events travel with the sample to the processing task.
    #[task(
        binds = TIM5,
        priority = 4,
        local = [
            sampler, samples_in, cfg_out,
            lost: u32 = 0,
            pps: Option<(u64, PpsEvent)> = None,
            overcapture: bool = false,
        ],
        shared = [acq]
    )]
    fn sample(mut cx: sample::Context) {
        // First action: both encoder counters (the board's timers; the simulated drive is
        // sampled at the sample's tick below).
        let entry_counts = cx.shared.acq.lock(|acq| acq.snapshot_now());
        let entry = board::cycles();
        let sampler = cx.local.sampler;
        let event = sampler.on_interrupt();
        if let Some(pps) = event.pps {
            // Reported with the next sample; a glitch does not hide an accepted edge.
            let keep = matches!(cx.local.pps, Some((_, e)) if *e != PpsEvent::Glitch)
                && pps.1 == PpsEvent::Glitch;
            if !keep {
                *cx.local.pps = Some(pps);
            }
        }
        *cx.local.overcapture |= event.overcapture;
        let Some(sample) = event.sample else {
            return;
        };
        let (counts, faults, sim_index) = cx.shared.acq.lock(|acq| {
            let counts = entry_counts.unwrap_or_else(|| acq.snapshot(sample.tick));
            (counts, acq.faults(sample.tick), acq.simulated_index())
        });
        while let Some(cfg) = cx.local.cfg_out.dequeue() {
            // A rejected configuration keeps the running one; the command task validated
            // it already (`discipline_config` of validated settings).
            let _ = sampler.set_config(cfg);
        }
        sampler.follow_clock();
        let raw = RawSample {
            sample,
            counts,
            faults,
            pps: cx.local.pps.take(),
            state: sampler.discipline().state(),
            stats: sampler.discipline().stats(),
            period: sampler.discipline().period(),
            sim_index,
            isr_cycles: board::cycles().wrapping_sub(entry),
            merged: event.merged,
            latency: event.latency,
            pps_overcapture: core::mem::take(cx.local.overcapture),
            queue_lost: *cx.local.lost,
        };
        if cx.local.samples_in.enqueue(raw).is_err() {
            *cx.local.lost = cx.local.lost.wrapping_add(1);
        }
        rtic::pend(Interrupt::SPI2);
    }

    /// Left index pulse: TIM2 latched the left counter at the edge (CH3 capture).
    #[task(binds = TIM2, priority = 4, local = [index_in_left], shared = [acq])]
    fn index_left(mut cx: index_left::Context) {
        if let Some(capture) = cx.shared.acq.lock(|acq| acq.take_index(0)) {
            let _ = cx.local.index_in_left.enqueue(capture);
        }
    }

    /// Right index pulse: TIM3 latched the right counter at the edge (CH4 capture).
    #[task(binds = TIM3, priority = 4, local = [index_in_right], shared = [acq])]
    fn index_right(mut cx: index_right::Context) {
        if let Some(capture) = cx.shared.acq.lock(|acq| acq.take_index(1)) {
            let _ = cx.local.index_in_right.enqueue(capture);
        }
    }

    /// NMEA bytes from the GNSS receiver.
    #[task(binds = USART1, priority = 3, local = [gnss, gnss_in], shared = [gnss_errors])]
    fn gnss_rx(mut cx: gnss_rx::Context) {
        let gnss = cx.local.gnss;
        let gnss_in = cx.local.gnss_in;
        cx.shared.gnss_errors.lock(|errors| {
            if let Some(byte) = gnss.on_interrupt(errors) {
                if gnss_in.enqueue(byte).is_err() {
                    errors.lost = errors.lost.wrapping_add(1);
                }
                if byte == b'\n' {
                    rtic::pend(Interrupt::SPI2);
                }
            }
        });
    }

    /// The host link: bytes out of the transmit ring, command bytes in.
    #[task(binds = USART2, priority = 3, local = [host, host_rx_in], shared = [link, host_errors])]
    fn host_uart(cx: host_uart::Context) {
        let host = cx.local.host;
        let rx = cx.local.host_rx_in;
        let received = (cx.shared.link, cx.shared.host_errors)
            .lock(|link, errors| host.on_interrupt(&mut link.ring, rx, errors));
        if received {
            rtic::pend(Interrupt::SPI3);
        }
    }

    /// Encodes `msg` as the next frame and queues it whole if it fits with `reserve` bytes to
    /// spare; false when it did not fit (nothing queued, sequence number unchanged). The
    /// frame is encoded outside the lock; if another task sent a frame meanwhile, it is
    /// encoded again with the new sequence number.
    fn send(link: &mut impl Mutex<T = Link>, msg: &Message, reserve: usize) -> bool {
        let mut buf = [0u8; protocol::MAX_ENCODED_FRAME];
        loop {
            let seq = link.lock(|l| l.next_seq);
            let Ok(n) = protocol::encode_frame(msg, seq, &mut buf) else {
                return false;
            };
            let queued = link.lock(|l| {
                if l.next_seq != seq {
                    None
                } else if l.ring.push_frame(&buf[..n], reserve) {
                    l.next_seq = seq.wrapping_add(1);
                    Some(true)
                } else {
                    Some(false)
                }
            });
            match queued {
                Some(true) => {
                    rtic::pend(Interrupt::USART2);
                    return true;
                }
                Some(false) => return false,
                None => continue,
            }
        }
    }

    /// Processing: counts to pose, records to the link (SPI2 vector, pended by the sampler).
    #[task(
        binds = SPI2,
        priority = 2,
        local = [samples_out, index_out_left, index_out_right, gnss_out, processor, led, watchdog],
        shared = [link, requests, live, host_errors, gnss_errors, store_state]
    )]
    fn process(mut cx: process::Context) {
        let p = cx.local.processor;
        while let Some(byte) = cx.local.gnss_out.dequeue() {
            p.on_nmea_byte(byte);
        }
        while let Some(raw) = cx.local.samples_out.dequeue() {
            let start = board::cycles();
            while let Some(l) = cx.local.index_out_left.dequeue() {
                p.on_index_capture(0, l);
            }
            while let Some(r) = cx.local.index_out_right.dequeue() {
                p.on_index_capture(1, r);
            }
            let requests = cx.shared.requests.lock(core::mem::take);
            p.apply(requests);
            let Some(record) = p.on_sample(&raw) else {
                continue;
            };
            cx.local.watchdog.feed();
            cx.local.led.set(raw.state == SyncState::Locked);
            if let Some(record) = record {
                let sent = send(&mut cx.shared.link, &Message::Pose(record), RECORD_RESERVE);
                p.sent(sent);
            }
            if p.heartbeat_due() {
                let store = cx.shared.store_state.lock(|s| *s);
                let rx_errors = cx.shared.host_errors.lock(|e| e.lost);
                let gnss_lost = cx.shared.gnss_errors.lock(|e| e.lost);
                let status = p.heartbeat(&raw, store, rx_errors, gnss_lost);
                // Like a record: sent whole when there is room, else skipped (the next one
                // follows a second later).
                send(
                    &mut cx.shared.link,
                    &Message::Status(status),
                    RECORD_RESERVE,
                );
            }
            let spent = board::cycles().wrapping_sub(start);
            let live = p.live(&raw, spent);
            cx.shared.live.lock(|l| *l = live);
        }
    }

    /// Commands from the host (SPI3 vector, pended by the USART2 interrupt).
    #[task(binds = SPI3, priority = 1, local = [host_rx_out, commands, cfg_in], shared = [link, requests, live, host_errors, gnss_errors, store_state])]
    fn commands_task(mut cx: commands_task::Context) {
        let c = cx.local.commands;
        while let Some(byte) = cx.local.host_rx_out.dequeue() {
            let (mut reply, action) = match c.assembler.push(byte) {
                None => continue,
                Some(Ok(line)) => command::execute(line, &mut c.settings),
                Some(Err(e)) => (Reply::error(e), Action::None),
            };
            match action {
                Action::None => {}
                Action::SettingsChanged => {
                    c.dirty = true;
                    cx.shared.store_state.lock(|s| s.dirty = true);
                    let cfg = discipline_config(&c.settings, c.timer_hz, c.clock);
                    if cx.local.cfg_in.enqueue(cfg).is_err() {
                        defmt::warn!("sampler configuration queue full");
                    }
                    let settings = c.settings;
                    cx.shared.requests.lock(|r| r.settings = Some(settings));
                }
                Action::Save
                    if cx.shared.live.lock(|l| l.moving)
                        && !c.settings.survives_stall(c.store.flash().max_stall_ms())
                        && c.store.next_save_erases().unwrap_or(true) =>
                {
                    reply = Reply::error(format_args!(
                        "save refused while the wheels turn: a flash erase stops the CPU for up to {} ms, longer than the right counter can go unread at max_wheel_speed; save at rest",
                        c.store.flash().max_stall_ms()
                    ));
                }
                Action::Save => match c.store.save(&c.settings) {
                    Ok(generation) => {
                        c.dirty = false;
                        c.source = SettingsSource::Flash;
                        cx.shared.store_state.lock(|s| {
                            *s = StoreState {
                                source: SettingsSource::Flash,
                                dirty: false,
                            }
                        });
                        defmt::info!("settings saved, generation {}", generation);
                        reply.push_line(format_args!("saved (generation {generation})"));
                    }
                    Err(e) => {
                        defmt::error!("settings save failed");
                        reply = Reply::error(format_args!("save failed: {e}"));
                    }
                },
                Action::ResetPose { x, y, heading } => {
                    cx.shared
                        .requests
                        .lock(|r| r.reset = Some(Pose { x, y, heading }));
                }
                Action::Status => {
                    let live = cx.shared.live.lock(|l| *l);
                    let rx_lost = cx.shared.host_errors.lock(|e| e.lost);
                    let gnss_lost = cx.shared.gnss_errors.lock(|e| e.lost);
                    c.status(&mut reply, &live, rx_lost, gnss_lost);
                }
                Action::Version => {
                    reply.push_line(format_args!(
                        "firmware = odo-unit {}",
                        env!("CARGO_PKG_VERSION")
                    ));
                    reply.push_line(format_args!("protocol = {PROTOCOL_VERSION}"));
                    let mut info = DeviceInfo {
                        protocol_version: PROTOCOL_VERSION,
                        settings_source: c.source,
                        settings_checksum: c.settings.checksum(),
                        uid: board::unique_id(),
                        firmware_version: heapless::String::new(),
                    };
                    let _ = info.firmware_version.push_str(env!("CARGO_PKG_VERSION"));
                    send_blocking(&mut cx.shared.link, &Message::DeviceInfo(info));
                }
            }
            for chunk in CommandReply::chunks(reply.ok, &reply.text) {
                send_blocking(&mut cx.shared.link, &Message::Reply(chunk));
            }
        }
    }

    /// Sends a reply frame, waiting for room (only the command task, the lowest priority,
    /// waits; the ring drains in the USART2 interrupt meanwhile).
    fn send_blocking(link: &mut impl Mutex<T = Link>, msg: &Message) {
        while !send(link, msg, 0) {
            cortex_m::asm::nop();
        }
    }

    /// State of the command task.
    pub struct Commands {
        assembler: LineAssembler,
        settings: Settings,
        store: SettingsStore<SettingsFlash>,
        source: SettingsSource,
        dirty: bool,
        timer_hz: u32,
        /// The clock source found at start.
        clock: ClockSource,
    }

    impl Commands {
        fn status(&self, reply: &mut Reply, live: &Live, rx_lost: u32, gnss_lost: u32) {
            let sync = match live.flags.sync {
                protocol::SyncMode::FreeRunning => "free",
                protocol::SyncMode::PpsLocked => "locked",
                protocol::SyncMode::Holdover => "holdover",
            };
            let on = |b: bool| if b { "yes" } else { "no" };
            let clock = match board::clock_source(self.clock) {
                ClockSource::Hse => "hse",
                ClockSource::Hsi => "hsi",
                ClockSource::HsiFallback => "hsi-fallback (HSE failed)",
            };
            reply.push_line(format_args!("clock = {clock}"));
            reply.push_line(format_args!("sync = {sync}"));
            reply.push_line(format_args!("time_valid = {}", on(live.flags.time_valid)));
            reply.push_line(format_args!("samples = {}", live.samples));
            reply.push_line(format_args!("mcu_time_us = {}", live.mcu_time_us));
            reply.push_line(format_args!("records_dropped = {}", live.dropped_total));
            reply.push_line(format_args!(
                "samples_lost = {}, merged_samples = {}",
                live.samples_lost, live.merged_samples
            ));
            let latency_ns = u64::from(live.latency_max) * 1_000_000_000 / u64::from(self.timer_hz);
            reply.push_line(format_args!("sample_latency_max = {latency_ns} ns"));
            reply.push_line(format_args!("second_ticks = {}", live.period));
            reply.push_line(format_args!(
                "pps_accepted = {}, pps_glitches = {}, pps_missed = {}, pps_locks = {}, pps_overcaptures = {}",
                live.stats.accepted,
                live.stats.glitches,
                live.stats.missed,
                live.stats.locks,
                live.pps_overcaptures
            ));
            reply.push_line(format_args!(
                "nmea_time_messages = {}, nmea_errors = {}, gnss_rx_lost = {gnss_lost}",
                live.time_messages, live.nmea_errors
            ));
            for (name, w, m, lost) in [
                (
                    "left",
                    live.flags.left,
                    live.index_mismatches[0],
                    live.index_lost[0],
                ),
                (
                    "right",
                    live.flags.right,
                    live.index_mismatches[1],
                    live.index_lost[1],
                ),
            ] {
                reply.push_line(format_args!(
                    "{name}: fault = {}, index_seen = {}, index_mismatches = {m}, index_lost = {lost}",
                    on(w.fault),
                    on(w.index_seen)
                ));
            }
            reply.push_line(format_args!("host_rx_lost = {rx_lost}"));
            let unit = if cfg!(feature = "qemu") {
                "instructions (QEMU)"
            } else {
                "cycles"
            };
            reply.push_line(format_args!(
                "sample_isr_max = {} {unit}, process_max = {} {unit}",
                live.isr_cycles_max, live.process_cycles_max
            ));
            reply.push_line(format_args!(
                "sample_isr_last = {} {unit}, process_last = {} {unit}",
                live.isr_cycles_last, live.process_cycles_last
            ));
            let (used, size) = board::stack::high_water();
            reply.push_line(format_args!("stack_used = {used} of {size} bytes"));
            let source = match self.source {
                SettingsSource::Flash => "flash",
                SettingsSource::Defaults => "defaults",
            };
            reply.push_line(format_args!(
                "settings = {source}, unsaved_changes = {}",
                on(self.dirty)
            ));
        }
    }

    /// State of the processing task: counts to records.
    pub struct Processor {
        timer_hz: u32,
        settings: Settings,
        extenders: Option<[CounterExtender; 2]>,
        integrator: Option<Integrator>,
        trackers: [IndexTracker; 2],
        /// Index mismatch not yet reported in a sent record.
        mismatch: [bool; 2],
        tagger: TimeTagger,
        nmea: LineBuffer,
        nmea_errors: u32,
        time_messages: u32,
        last_tick: u64,
        sequence: u32,
        dropped_since: u32,
        dropped_total: u32,
        last_state: SyncState,
        last_faults: (bool, bool),
        reset: Option<Pose>,
        flags: StatusFlags,
        mcu_time_us: u64,
        isr_cycles_max: u32,
        process_cycles_max: u32,
        merged_samples: u32,
        latency_max: u32,
        index_lost: [u32; 2],
        pps_overcaptures: u32,
        /// Counts of the last sample, and the sample sequence at which they last changed.
        last_counts: Option<(u32, u32)>,
        last_motion: u32,
    }

    impl Processor {
        fn new(settings: &Settings, timer_hz: u32) -> Self {
            let tpr = settings.chassis.ticks_per_rev;
            Self {
                timer_hz,
                settings: *settings,
                extenders: None,
                integrator: None,
                trackers: [IndexTracker::new(tpr, DEFAULT_TOLERANCE); 2],
                mismatch: [false; 2],
                tagger: TimeTagger::new(time_tag(settings), u64::from(timer_hz)),
                nmea: LineBuffer::new(),
                nmea_errors: 0,
                time_messages: 0,
                last_tick: 0,
                sequence: 0,
                dropped_since: 0,
                dropped_total: 0,
                last_state: SyncState::FreeRunning,
                last_faults: (false, false),
                reset: None,
                flags: StatusFlags::default(),
                mcu_time_us: 0,
                isr_cycles_max: 0,
                process_cycles_max: 0,
                merged_samples: 0,
                latency_max: 0,
                index_lost: [0; 2],
                pps_overcaptures: 0,
                last_counts: None,
                last_motion: 0,
            }
        }

        /// An index pulse latched by the wheel's timer.
        fn on_index_capture(&mut self, wheel: usize, capture: IndexCapture) {
            if capture.overcapture {
                self.index_lost[wheel] = self.index_lost[wheel].wrapping_add(1);
                defmt::warn!("wheel {}: index pulse lost (over-capture)", wheel);
            }
            self.on_index(wheel, capture.raw);
        }

        fn on_nmea_byte(&mut self, byte: u8) {
            match self.nmea.push(byte) {
                None | Some(Err(NmeaError::Unsupported)) => {}
                Some(Err(_)) => self.nmea_errors = self.nmea_errors.wrapping_add(1),
                Some(Ok(msg)) if msg.valid() => match msg.time().gps_seconds() {
                    Ok(gps) => {
                        self.time_messages = self.time_messages.wrapping_add(1);
                        self.tagger.on_message(gps, self.last_tick);
                    }
                    Err(_) => self.nmea_errors = self.nmea_errors.wrapping_add(1),
                },
                Some(Ok(_)) => {}
            }
        }

        fn on_index(&mut self, wheel: usize, raw: u32) {
            let Some(ext) = &self.extenders else {
                return;
            };
            let count = ext[wheel].absolute_of(raw);
            match self.trackers[wheel].on_index(count) {
                IndexCheck::Mismatch { error } => {
                    self.mismatch[wheel] = true;
                    defmt::warn!(
                        "wheel {}: index count mismatch of {} increments",
                        wheel,
                        error
                    );
                }
                IndexCheck::First => defmt::info!("wheel {}: first index pulse", wheel),
                IndexCheck::Whole { .. } => {}
            }
        }

        fn apply(&mut self, requests: Requests) {
            if let Some(settings) = requests.settings {
                if let Some(integrator) = &mut self.integrator {
                    if integrator.set_params(&settings.chassis).is_err() {
                        defmt::error!("chassis parameters rejected by the integrator");
                    }
                }
                for t in &mut self.trackers {
                    t.set_ticks_per_rev(settings.chassis.ticks_per_rev);
                }
                self.tagger.set_assoc(time_tag(&settings));
                self.settings = settings;
            }
            if requests.reset.is_some() {
                self.reset = requests.reset;
            }
        }

        fn mcu_time_us(&self, tick: u64) -> u64 {
            let hz = u64::from(self.timer_hz);
            tick / hz * 1_000_000 + tick % hz * 1_000_000 / hz
        }

        /// Integrates one sample. `None` when nothing was integrated (never, today);
        /// `Some(None)` when the record is not sent (`output_divider`).
        fn on_sample(&mut self, raw: &RawSample) -> Option<Option<PoseRecord>> {
            if raw.merged > 0 {
                self.merged_samples = self.merged_samples.wrapping_add(raw.merged);
                defmt::warn!(
                    "sample interrupt late by {} ticks: {} samples merged",
                    raw.latency,
                    raw.merged
                );
            }
            self.latency_max = self.latency_max.max(raw.latency);
            if raw.pps_overcapture {
                self.pps_overcaptures = self.pps_overcaptures.wrapping_add(1);
                defmt::warn!("PPS: over-capture (two edges in one interrupt)");
            }
            let counts_now = (raw.counts.left, raw.counts.right);
            if self.last_counts != Some(counts_now) {
                self.last_counts = Some(counts_now);
                self.last_motion = self.sequence;
            }
            let counts = match &mut self.extenders {
                Some(ext) => {
                    ext[0].update(raw.counts.left);
                    ext[1].update(raw.counts.right);
                    WheelCounts {
                        left: ext[0].absolute(),
                        right: ext[1].absolute(),
                    }
                }
                None => {
                    let ext = [
                        CounterExtender::new(LEFT_BITS, raw.counts.left),
                        CounterExtender::new(RIGHT_BITS, raw.counts.right),
                    ];
                    let counts = WheelCounts {
                        left: ext[0].absolute(),
                        right: ext[1].absolute(),
                    };
                    self.extenders = Some(ext);
                    counts
                }
            };
            for (wheel, pulse) in raw.sim_index.iter().enumerate() {
                if let Some(r) = pulse {
                    self.on_index(wheel, *r);
                }
            }
            let refs = IndexRefs {
                left: self.trackers[0].reference(),
                right: self.trackers[1].reference(),
            };
            let mut step = Default::default();
            match &mut self.integrator {
                None => {
                    let pose = self.reset.take().unwrap_or_default();
                    let integrator = Integrator::new(&self.settings.chassis, counts, pose)
                        .or_else(|_| Integrator::new(&ChassisParams::DESIGNED, counts, pose));
                    match integrator {
                        Ok(i) => self.integrator = Some(i),
                        Err(_) => defmt::error!("integrator rejected the designed parameters"),
                    }
                }
                Some(integrator) => {
                    if let Some(pose) = self.reset.take() {
                        integrator.rebase_counts(counts);
                        integrator.reset_pose(pose);
                        defmt::info!("pose reset");
                    } else {
                        step = integrator.step(counts, refs);
                    }
                }
            }
            if step.overrange {
                defmt::warn!(
                    "sample {}: motion beyond one sample's limits, not integrated",
                    self.sequence
                );
            }

            // Timing: PPS edges, state changes, GNSS time of the sample.
            if let Some((tick, event)) = raw.pps {
                match event {
                    PpsEvent::Locked { second } => {
                        defmt::info!("PPS: locked");
                        self.tagger.on_edge(tick, second);
                    }
                    PpsEvent::Accepted { second, .. } => self.tagger.on_edge(tick, second),
                    PpsEvent::Reacquired { second, missed, .. } => {
                        defmt::info!("PPS: reacquired after {} lost pulses", missed);
                        self.tagger.on_edge(tick, second);
                    }
                    PpsEvent::Glitch => defmt::warn!("PPS: glitch rejected"),
                    PpsEvent::Ignored | PpsEvent::Candidate => {}
                }
            }
            if raw.state != self.last_state {
                defmt::info!(
                    "sampling: {} -> {}",
                    state_name(self.last_state),
                    state_name(raw.state)
                );
                if raw.state == SyncState::FreeRunning {
                    self.tagger.invalidate();
                }
                self.last_state = raw.state;
            }
            if raw.faults != self.last_faults {
                defmt::warn!(
                    "encoder fault lines: left {}, right {}",
                    raw.faults.0,
                    raw.faults.1
                );
                self.last_faults = raw.faults;
            }
            self.last_tick = raw.sample.tick;
            let gps = match raw.state {
                SyncState::FreeRunning => None,
                _ => self.tagger.gps_time(raw.sample.second),
            };

            let sequence = self.sequence;
            self.sequence = self.sequence.wrapping_add(1);
            let status = |wheel: usize, fault: bool, calibrated: bool| WheelStatus {
                fault,
                index_seen: self.trackers[wheel].seen(),
                index_mismatch: self.mismatch[wheel],
                calibrated,
            };
            self.flags = StatusFlags {
                sync: match raw.state {
                    SyncState::FreeRunning => protocol::SyncMode::FreeRunning,
                    SyncState::Locked => protocol::SyncMode::PpsLocked,
                    SyncState::Holdover => protocol::SyncMode::Holdover,
                },
                time_valid: gps.is_some(),
                left: status(0, raw.faults.0, step.left_referenced),
                right: status(1, raw.faults.1, step.right_referenced),
                model: self.settings.chassis.uncertainty_model,
            };
            self.mcu_time_us = self.mcu_time_us(raw.sample.tick);
            if sequence % self.settings.output_divider.max(1) != 0 {
                return Some(None);
            }
            let integrator = self.integrator.as_ref()?;
            let pose = integrator.pose();
            let sigma = integrator.sigma();
            Some(Some(PoseRecord {
                sequence,
                flags: self.flags,
                mcu_time_us: self.mcu_time_us,
                gnss: gps.map_or(GnssTime::default(), |g| GnssTime {
                    week: g.week,
                    tow_ms: g.tow * 1000,
                    sample_in_second: raw.sample.index as u16,
                }),
                x: pose.x,
                y: pose.y,
                heading: pose.heading,
                sigma_x: sigma.x,
                sigma_y: sigma.y,
                sigma_heading: sigma.heading,
                sigma_xy: sigma.xy,
                gamma_left: counts.left,
                gamma_right: counts.right,
                index_left: refs.left.unwrap_or(0),
                index_right: refs.right.unwrap_or(0),
                dropped: self.dropped_since,
            }))
        }

        /// True when the sample just processed starts a new second of samples: time for the
        /// once-a-second Status heartbeat.
        fn heartbeat_due(&self) -> bool {
            self.sequence.wrapping_sub(1) % self.settings.rate.max(1) == 0
        }

        /// The Status heartbeat after sample `raw`.
        fn heartbeat(
            &self,
            raw: &RawSample,
            store: StoreState,
            rx_errors: u32,
            gnss_lost: u32,
        ) -> Status {
            Status {
                uptime_us: self.mcu_time_us,
                flags: self.flags,
                rate_hz: self.settings.rate,
                samples: self.sequence,
                dropped_total: self.dropped_total,
                pps_edges: raw.stats.accepted,
                pps_rejected: raw.stats.glitches,
                rx_errors,
                settings_source: store.source,
                settings_dirty: store.dirty,
                samples_lost: raw.queue_lost,
                gnss_rx_lost: gnss_lost,
                merged_samples: self.merged_samples,
            }
        }

        /// The record was queued (true) or dropped for lack of room (false).
        fn sent(&mut self, sent: bool) {
            if sent {
                self.dropped_since = 0;
                self.mismatch = [false; 2];
            } else {
                self.dropped_since = self.dropped_since.saturating_add(1);
                self.dropped_total = self.dropped_total.saturating_add(1);
            }
        }

        fn live(&mut self, raw: &RawSample, process_cycles: u32) -> Live {
            self.isr_cycles_max = self.isr_cycles_max.max(raw.isr_cycles);
            self.process_cycles_max = self.process_cycles_max.max(process_cycles);
            Live {
                isr_cycles_max: self.isr_cycles_max,
                process_cycles_max: self.process_cycles_max,
                isr_cycles_last: raw.isr_cycles,
                process_cycles_last: process_cycles,
                samples: self.sequence,
                dropped_total: self.dropped_total,
                flags: self.flags,
                stats: raw.stats,
                period: raw.period,
                index_mismatches: [self.trackers[0].mismatches(), self.trackers[1].mismatches()],
                nmea_errors: self.nmea_errors,
                time_messages: self.time_messages,
                mcu_time_us: self.mcu_time_us,
                samples_lost: raw.queue_lost,
                merged_samples: self.merged_samples,
                latency_max: self.latency_max,
                index_lost: self.index_lost,
                pps_overcaptures: self.pps_overcaptures,
                moving: self.sequence.wrapping_sub(self.last_motion) <= self.settings.rate.max(1),
            }
        }
    }
}
