//! The RTIC application of the odometry unit (STM32F401): tasks, resources and queues
//! around `odo_unit` (what each task decides lives in `odo_unit::unit`).
//!
//! Data path of one sample: a TIM5 compare match is the sample instant (the grid comes
//! from the PPS discipline, `odo_unit::timing::pps`); the TIM5 interrupt (priority 4)
//! snapshots both encoder counters as its first action, then the fault lines, labels the
//! instant (`odo_unit::timing::catch_up`, which also merges the points a stall passed over)
//! and hands an `odo_unit::unit::RawSample` to the processing task through a lock-free
//! queue. The processing task (priority 2) extends the counters to 64 bits, applies index pulses, integrates, tags GNSS time, builds the pose
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
#[cfg(target_os = "none")]
mod host_link;
#[cfg(target_os = "none")]
mod log;
#[cfg(target_os = "none")]
mod panic;

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use crate::board::{
        self,
        flash::SettingsFlash,
        sampler::Sampler,
        serial::{GnssUart, HostUart, RxErrors},
        Acquisition, GnssRx, Led,
    };
    use crate::host_link::{
        queue_now, send, send_blocking, send_mavlink, Link, RECORD_RESERVE, SENTENCE_RESERVE,
    };
    use heapless::spsc::{Consumer, Producer, Queue};
    use odo_unit::mavlink::{FrameBuf, Ids, MavlinkOut};
    use odo_unit::protocol::{CommandReply, Message};
    use odo_unit::settings::store::SettingsStore;
    use odo_unit::settings::Output;
    use odo_unit::timing::{DisciplineConfig, SyncState};
    use odo_unit::unit::{
        self, Commands, Effect, HeartbeatInputs, IndexCapture, Live, PpsLatch, Processor,
        RawSample, Requests, SampleOutcome, StoreState,
    };
    use stm32f4xx_hal::pac::Interrupt;
    use stm32f4xx_hal::watchdog::IndependentWatchdog;

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
        index_out: [Consumer<'static, IndexCapture>; 2],
        host: HostUart,
        host_rx_in: Producer<'static, u8>,
        host_rx_out: Consumer<'static, u8>,
        gnss: GnssRx,
        gnss_in: Producer<'static, u8>,
        gnss_out: Consumer<'static, u8>,
        line_end_in: Producer<'static, u32>,
        line_end_out: Consumer<'static, u32>,
        cfg_in: Producer<'static, DisciplineConfig>,
        cfg_out: Consumer<'static, DisciplineConfig>,
        processor: Processor,
        commands: Commands<SettingsFlash>,
        led: Led,
        watchdog: IndependentWatchdog,
    }

    #[init(local = [
        samples_q: Queue<RawSample, 32> = Queue::new(),
        index_left_q: Queue<IndexCapture, 16> = Queue::new(),
        index_right_q: Queue<IndexCapture, 16> = Queue::new(),
        host_rx_q: Queue<u8, 512> = Queue::new(),
        gnss_q: Queue<u8, 512> = Queue::new(),
        line_end_q: Queue<u32, 16> = Queue::new(),
        cfg_q: Queue<DisciplineConfig, 4> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        board::stack::paint();
        let dp = cx.device;
        let mut core = cx.core;
        board::start_cycle_counter(&mut core);
        // The watchdog first (it runs from the LSI): nothing after this can hang for good.
        let watchdog = board::start_watchdog(dp.IWDG, &dp.DBGMCU);
        let reset_cause = board::take_reset_cause(&dp.RCC);
        let (mut rcc, clock, clocks) = board::start_clocks(dp.RCC);
        let timer_hz = board::timer_hz(&clocks);

        let pins = board::pins(dp.GPIOA, dp.GPIOB, dp.GPIOC, &mut rcc);

        // Settings: the newest valid record in flash, else the defaults.
        let flash = SettingsFlash::new(dp.FLASH);
        let mut store = SettingsStore::new(flash);
        let loaded = store.load_or_defaults();
        let clock_now = board::clock_source(clock);
        let Ok(start) = unit::start(loaded.settings, timer_hz, clock_now, clock) else {
            panic!("default sampler configuration rejected")
        };
        crate::log::start(clock, &loaded, &start);
        let settings = start.settings;

        let mut acq = Acquisition::new(dp.TIM2, dp.TIM3, pins.faults, &mut rcc);

        let host = HostUart::new(dp.USART2, &mut rcc, clocks.pclk1, settings.baud);
        let gnss = GnssUart::new(dp.USART1, &mut rcc, clocks.pclk2, settings.gnss_baud);
        // QEMU: PPS captures and NMEA bytes from the simulated receiver (board/qemu/gnss.rs).
        let (gnss, sampler_extra) = board::attach_gnss(gnss, settings.gnss_baud);

        let (mut samples_in, samples_out) = cx.local.samples_q.split();
        let (index_in_left, index_out_left) = cx.local.index_left_q.split();
        let (index_in_right, index_out_right) = cx.local.index_right_q.split();
        let (host_rx_in, host_rx_out) = cx.local.host_rx_q.split();
        let (gnss_in, gnss_out) = cx.local.gnss_q.split();
        let (line_end_in, line_end_out) = cx.local.line_end_q.split();
        let (cfg_in, cfg_out) = cx.local.cfg_q.split();

        let cfg = *start.discipline.config();
        let (sampler, s0) = Sampler::start(dp.TIM5, &mut rcc, start.discipline, sampler_extra);
        // Sample 0 is now: snapshot it as the starting point of the integration.
        let (counts, faults) = (acq.snapshot(s0.tick), acq.faults(s0.tick));
        let first = RawSample::first(s0, counts, faults, sampler.discipline());
        let _ = samples_in.enqueue(first);
        rtic::pend(Interrupt::SPI2);

        crate::log::booted(timer_hz, &cfg);

        let processor = Processor::new(&settings, timer_hz, board::COUNTER_BITS);
        let commands = Commands::new(settings, loaded.source, store, timer_hz, clock)
            .with_stored(loaded.settings);
        // DeviceInfo is the first frame (sequence 0): receivers see a restart by it.
        let mut link = Link::new();
        let info = commands.device_info(board::unique_id(), reset_cause);
        queue_now(&mut link, &Message::DeviceInfo(info));
        let shared = Shared {
            acq,
            link,
            requests: Requests::default(),
            live: Live::default(),
            host_errors: RxErrors::default(),
            gnss_errors: RxErrors::default(),
            store_state: commands.store_state(),
        };
        let local = Local {
            sampler,
            samples_in,
            samples_out,
            index_in_left,
            index_in_right,
            index_out: [index_out_left, index_out_right],
            host,
            host_rx_in,
            host_rx_out,
            gnss,
            gnss_in,
            gnss_out,
            line_end_in,
            line_end_out,
            cfg_in,
            cfg_out,
            processor,
            commands,
            led: pins.led,
            watchdog,
        };
        (shared, local)
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            board::keep_debug_port_awake();
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
            pps: PpsLatch = PpsLatch::new(),
        ],
        shared = [acq]
    )]
    fn sample(mut cx: sample::Context) {
        // First action: both encoder counters (the board's timers; the simulated drive is
        // sampled at the sample's tick below).
        let entry_counts = cx.shared.acq.lock(|acq| acq.snapshot_now());
        let entry = board::cycles();
        let sampler = cx.local.sampler;
        // Before the grid advances: a rate set before the first sample of a second applies
        // from that sample on.
        while let Some(cfg) = cx.local.cfg_out.dequeue() {
            // A rejected configuration keeps the running one; the command task validated
            // it already (`discipline_config` of validated settings).
            let _ = sampler.set_config(cfg);
        }
        let event = sampler.on_interrupt();
        // Reported with the next sample.
        cx.local.pps.on_interrupt(event.pps, event.overcapture);
        let Some(sample) = event.sample else {
            return;
        };
        let (counts, faults, index_pulses) = cx.shared.acq.lock(|acq| {
            let counts = entry_counts.unwrap_or_else(|| acq.snapshot(sample.tick));
            (counts, acq.faults(sample.tick), acq.sample_index())
        });
        sampler.follow_clock();
        let (pps, pps_overcapture) = cx.local.pps.take();
        let raw = RawSample {
            sample,
            counts,
            faults,
            pps,
            state: sampler.discipline().state(),
            stats: sampler.discipline().stats(),
            period: sampler.discipline().period(),
            index_pulses,
            isr_cycles: board::cycles().wrapping_sub(entry),
            merged: event.merged,
            latency: event.latency,
            pps_overcapture,
            queue_lost: *cx.local.lost,
        };
        if let Err(raw) = cx.local.samples_in.enqueue(raw) {
            *cx.local.lost = cx.local.lost.wrapping_add(1);
            cx.local.pps.put_back(&raw);
        }
        rtic::pend(Interrupt::SPI2);
    }

    /// Left index pulse: TIM2 latched the left counter at the edge (CH3 capture).
    #[task(binds = TIM2, priority = 4, local = [index_in_left, lost: u32 = 0], shared = [acq])]
    fn index_left(mut cx: index_left::Context) {
        if let Some(capture) = cx.shared.acq.lock(|acq| acq.take_index(0)) {
            capture.queue(cx.local.lost, |c| cx.local.index_in_left.enqueue(c).is_ok());
        }
    }

    /// Right index pulse: TIM3 latched the right counter at the edge (CH4 capture).
    #[task(binds = TIM3, priority = 4, local = [index_in_right, lost: u32 = 0], shared = [acq])]
    fn index_right(mut cx: index_right::Context) {
        if let Some(capture) = cx.shared.acq.lock(|acq| acq.take_index(1)) {
            capture.queue(cx.local.lost, |c| {
                cx.local.index_in_right.enqueue(c).is_ok()
            });
        }
    }

    /// NMEA bytes from the GNSS receiver; a line ending (CR, LF) goes with the tick it
    /// arrived at, or is dropped and counted as lost with it when either queue is full.
    #[task(
        binds = USART1,
        priority = 3,
        local = [gnss, gnss_in, line_end_in],
        shared = [gnss_errors]
    )]
    fn gnss_rx(mut cx: gnss_rx::Context) {
        let gnss = cx.local.gnss;
        let gnss_in = cx.local.gnss_in;
        let line_end_in = cx.local.line_end_in;
        cx.shared.gnss_errors.lock(|errors| {
            if let Some(byte) = gnss.on_interrupt(errors) {
                let line_end = byte == b'\r' || byte == b'\n';
                if !gnss_in.ready() || (line_end && !line_end_in.ready()) {
                    errors.on_queue_full();
                    return;
                }
                if line_end {
                    let _ = line_end_in.enqueue(board::tick_now());
                }
                let _ = gnss_in.enqueue(byte);
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
            .lock(|link, errors| host.on_interrupt(link.ring(), rx, errors));
        if received {
            rtic::pend(Interrupt::SPI3);
        }
    }

    /// Processing: counts to pose, records to the link (SPI2 vector, pended by the sampler).
    #[task(
        binds = SPI2,
        priority = 2,
        local = [
            samples_out, index_out, gnss_out, line_end_out, processor, led, watchdog,
            mav: MavlinkOut = MavlinkOut::new(),
        ],
        shared = [link, requests, live, host_errors, gnss_errors, store_state]
    )]
    fn process(mut cx: process::Context) {
        let p = cx.local.processor;
        let log = &mut crate::log::Defmt;
        // GNSS lines first (the time tag of the samples below); a forwarded sentence is
        // queued only with room left for the next Status and record (`SENTENCE_RESERVE`).
        while let Some(byte) = cx.local.gnss_out.dequeue() {
            let line_end = match byte {
                b'\r' | b'\n' => cx.local.line_end_out.dequeue(),
                _ => None,
            };
            if let Some(sentence) = p.on_nmea_byte(byte, line_end) {
                let msg = Message::Gnss(sentence);
                let sent = send(&mut cx.shared.link, &msg, SENTENCE_RESERVE);
                p.gnss_sent(sent);
            }
        }
        while let Some(raw) = cx.local.samples_out.dequeue() {
            let start = board::cycles();
            for (wheel, captures) in cx.local.index_out.iter_mut().enumerate() {
                while let Some(capture) = captures.dequeue() {
                    p.on_index_capture(wheel, capture, log);
                }
            }
            let requests = cx.shared.requests.lock(core::mem::take);
            p.apply(requests, log);
            let outcome = p.on_sample(&raw, log);
            let record = match &outcome {
                SampleOutcome::Record(record) => Some(record),
                SampleOutcome::Skipped => None,
                SampleOutcome::NoIntegrator => continue,
            };
            cx.local.watchdog.feed();
            cx.local.led.set(raw.state == SyncState::Locked);
            // The second's Status before its first record (it announces a rate switch);
            // without room, tried again with the next sample.
            // `output = mavlink`: HEARTBEAT and ODOMETRY instead of Status and the record.
            let mavlink = p.settings().output == Output::Mavlink;
            let ids = Ids::of(p.settings());
            let mav = &mut *cx.local.mav;
            let mut frame: FrameBuf = [0; core::mem::size_of::<FrameBuf>()];
            if p.heartbeat_due() {
                let sent = if mavlink {
                    let n = mav.heartbeat(ids, &mut frame);
                    send_mavlink(&mut cx.shared.link, &mut frame, n, RECORD_RESERVE)
                } else {
                    let inputs = HeartbeatInputs {
                        store: cx.shared.store_state.lock(|s| *s),
                        host: cx.shared.host_errors.lock(|e| *e),
                        gnss: cx.shared.gnss_errors.lock(|e| *e),
                        reset_cause: board::reset_cause(),
                    };
                    let status = Message::Status(p.heartbeat(&raw, &inputs));
                    send(&mut cx.shared.link, &status, RECORD_RESERVE)
                };
                if mavlink {
                    mav.sent(sent);
                }
                p.status_sent(sent);
            }
            if let Some(record) = record {
                let sent = if mavlink {
                    let n = mav.odometry(
                        record,
                        &p.settings().chassis,
                        p.pose_resets(),
                        ids,
                        &mut frame,
                    );
                    let sent = send_mavlink(&mut cx.shared.link, &mut frame, n, RECORD_RESERVE);
                    mav.sent(sent);
                    sent
                } else {
                    mav.restart();
                    send(&mut cx.shared.link, &Message::Pose(*record), RECORD_RESERVE)
                };
                p.sent(sent);
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
            let (at_start, live) = (c.clock_at_start(), &mut cx.shared.live);
            let clock = move || board::clock_source(at_start);
            let Some((mut reply, effect)) = c.on_byte(byte, clock, || live.lock(|l| l.moving))
            else {
                continue;
            };
            match effect {
                Effect::None => {}
                Effect::SettingsChanged {
                    settings,
                    discipline,
                } => {
                    cx.shared.store_state.lock(|s| *s = c.store_state());
                    // The processing task first: it switches `output_divider` only once
                    // the samples have the new rate, whichever sample that is.
                    cx.shared.requests.lock(|r| r.settings = Some(settings));
                    if cx.local.cfg_in.enqueue(discipline).is_err() {
                        defmt::warn!("sampler configuration queue full");
                    }
                }
                Effect::Saved { generation } => {
                    let state = c.store_state();
                    cx.shared.store_state.lock(|s| *s = state);
                    defmt::info!("settings saved, generation {}", generation);
                }
                Effect::SaveFailed => defmt::error!("settings save failed"),
                Effect::ResetPose(pose) => cx.shared.requests.lock(|r| r.reset = Some(pose)),
                Effect::Status => {
                    let live = cx.shared.live.lock(|l| *l);
                    let host = cx.shared.host_errors.lock(|e| *e);
                    let gnss = cx.shared.gnss_errors.lock(|e| *e);
                    let board = board::report(c.clock_at_start());
                    c.status(&mut reply, &live, &host, &gnss, &board);
                }
                Effect::Version => {
                    let info = c.version(&mut reply, board::unique_id(), board::reset_cause());
                    send_blocking(&mut cx.shared.link, &Message::DeviceInfo(info));
                }
            }
            for chunk in CommandReply::chunks(reply.ok, &reply.text) {
                send_blocking(&mut cx.shared.link, &Message::Reply(chunk));
            }
        }
    }
}
