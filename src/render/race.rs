//! The race: whether a guide's passes pay for their time against plain path
//! tracing's, measured on the render itself.
//!
//! At each stand-back check from the 16th pass on (see
//! `crate::guide::stand_back_check`) a guide that has not stood back runs
//! four passes that learn nothing: plain, guided, guided, plain (so that
//! whatever slows the machine slows both). Each pass's noise is its samples'
//! squared deviation from their pixels' means when the race began, less
//! those means' own variance, relative as relMSE weighs it (the accumulate
//! kernel totals it against a copy of the accumulation); its cost is that
//! noise times the pass's time. Every pass is unbiased and counts in the
//! image, so the race only decides which kernel the passes after it run.
//!
//! Most of a pass's noise can be common to both kernels: a camera ray that
//! lands on a light's edge, a light sample near a light. So the laps run in
//! pairs on the same random numbers (the second of a pair draws those of
//! the first; each sample stays unbiased, the two are merely correlated),
//! and a spike that lands in one lands in the other. Such a spike still
//! swells both entrants' noise alike and so pulls their ratio toward 1,
//! where plain path tracing, whose passes are cheaper, wins: plain path
//! tracing wins a race only where it wins in each pair of laps.
//!
//! A lap's noise is measured on its samples alone, so light that plain path
//! tracing finds too rarely to show in one lap (a sun seen through a window
//! pane, which only a bounce's direction can find) leaves its noise looking
//! small: in a 128x128 sky room with a glass pane, a plain lap that met no
//! sun measured 0.001x the guide's noise times time, and one render in six
//! stood back, where the guide reaches 0.11-0.13x plain path tracing's
//! error at equal time. Every lap estimates the same image, so a plain lap
//! whose image mean falls short of the image's mean by more than its own
//! noise and that mean's allow has missed such light, and its pair is not
//! plain path tracing's. The image's mean is the accumulation's when the
//! race began together with the guided laps', weighed by their variances.

use serde::{Deserialize, Serialize};

/// The kernel a race pass runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Entrant {
    Plain,
    Guide,
}

/// The race's passes, in order: two pairs.
pub const LAPS: [Entrant; 4] = [
    Entrant::Plain,
    Entrant::Guide,
    Entrant::Guide,
    Entrant::Plain,
];

/// One pass of a race.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Lap {
    pub entrant: Entrant,
    /// Draws the random numbers of the pass before it (the second of a pair).
    pub repeat: bool,
}

/// The first check that races. Up to 16 passes the guides learn in every
/// pass and their noise still falls fast: on the glossy Cornell box with NEE
/// a race after 8 passes put the guide at 0.91-1.08x plain path tracing's
/// noise per second, and after 16 at 1.37-1.41x (later 1.6-5x).
pub const FIRST: u32 = 16;

/// The fewest pixels (one sample each a pass) of an image whose renders race:
/// a pass of fewer samples shows too little of light found rarely. At 64x64
/// the glass scene's races (`neural --nee`) put plain path tracing's noise
/// times time at 0.18x and 0.27x the guide's and it stood back, where kept
/// the guide has 0.74x the error at equal time; at 128x128 its races read
/// 1.4-2.4x and none stood back (2026-12-07).
pub const MIN_PIXELS: u64 = 128 * 128;

/// Plain path tracing wins a race where its cost is lower by this factor,
/// in each pair of laps: the guide keeps learning after the race, and one
/// pass's noise is itself noisy. The guide stands back once plain path
/// tracing has won two races in a row.
pub const MARGIN: f64 = 1.25;

/// A plain lap missed light where its image mean falls short of the image's
/// by this many standard errors of their difference, and by [`MISSED_SHARE`]
/// of the image's mean (see the module's notes).
pub const MISSED_SIGMAS: f64 = 3.0;
pub const MISSED_SHARE: f64 = 0.1;

/// What one lap measured: a pass of one sample per pixel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LapNoise {
    pub seconds: f64,
    /// Mean relative squared deviation of its samples (see the module's notes).
    pub deviation: f64,
    /// Its image's mean value (the mean of the channels), and the variance
    /// of a sample's value.
    pub mean: f64,
    pub variance: f64,
    /// Its samples, one per pixel.
    pub samples: f64,
    /// The image's mean value when the race began, and a bound on that
    /// mean's variance.
    pub reference: f64,
    pub reference_variance: f64,
}

impl LapNoise {
    /// From a pass's totals of its samples' values, their squares, their
    /// pixels' reference means and those means' variances (one sample a pixel).
    pub fn new(seconds: f64, deviation: f64, samples: f64, totals: [f64; 4]) -> Self {
        let n = samples.max(1.0);
        let mean = totals[0] / n;
        Self {
            seconds,
            deviation,
            mean,
            variance: (totals[1] / n - mean * mean).max(0.0),
            samples,
            reference: totals[2] / n,
            reference_variance: totals[3] / (n * n),
        }
    }

    /// The variance of the lap's image mean.
    fn mean_variance(&self) -> f64 {
        self.variance / self.samples.max(1.0)
    }

    /// Whether this (plain) lap missed light: its image mean is too far below
    /// the image's, `image` (mean, variance), for either's noise to explain.
    fn missed_light(&self, image: (f64, f64)) -> bool {
        let error = (self.mean_variance() + image.1).sqrt();
        image.0 - self.mean > (MISSED_SIGMAS * error).max(MISSED_SHARE * image.0)
    }
}

/// The image's mean and its variance from the race's reference and guided
/// laps: the guided laps' mean weighed against the reference's by their
/// variances.
fn image_mean(guided: &[LapNoise]) -> (f64, f64) {
    let Some(first) = guided.first() else {
        return (0.0, 0.0);
    };
    let n = guided.len() as f64;
    let laps = guided.iter().map(|l| l.mean).sum::<f64>() / n;
    let laps_variance = guided.iter().map(LapNoise::mean_variance).sum::<f64>() / (n * n);
    let (a, b) = (
        first.reference_variance.max(1e-30),
        laps_variance.max(1e-30),
    );
    ((first.reference * b + laps * a) / (a + b), a * b / (a + b))
}

/// What a race measured and what it decided (kept in the render's stats).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RaceRecord {
    /// The check after which it ran.
    pub after: u32,
    /// Mean relative squared deviation of a plain sample, and of a guided one.
    pub plain_deviation: f64,
    pub guide_deviation: f64,
    /// Seconds per pass: plain; the guide's passes that learn nothing; and
    /// the guide's passes to come, learning as often as its schedule says.
    pub plain_seconds: f64,
    pub guide_seconds: f64,
    pub guide_future_seconds: f64,
    /// Plain deviation × seconds over the guide's, the guide's to come.
    pub plain_over_guide: f64,
    /// The same for each pair of laps alone (deviations of the pair, the
    /// race's seconds); empty in records from before it was kept.
    #[serde(default)]
    pub plain_over_guide_pairs: Vec<f64>,
    /// Each pair whose plain lap missed light (see [`MISSED_SIGMAS`]); such a
    /// pair is not plain path tracing's.
    #[serde(default)]
    pub plain_missed_pairs: Vec<bool>,
    /// Plain path tracing won this race (its cost lower by [`MARGIN`] in
    /// every pair of laps, none of which missed light)...
    pub plain_wins: bool,
    /// ...and the one before, so the guide stands back.
    pub stands_back: bool,
}

/// Passes of the guide's ordinary kind since the last check: their time and
/// how many of them learned.
#[derive(Clone, Copy, Debug, Default)]
pub struct Window {
    pub seconds: f64,
    pub passes: u32,
    pub learning: u32,
}

impl Window {
    pub fn add(&mut self, seconds: f64, passes: u32, learning: u32) {
        self.seconds += seconds;
        self.passes += passes;
        self.learning += learning;
    }
}

/// A race in progress.
#[derive(Clone, Debug)]
pub struct Race {
    /// The check after which it runs.
    pub after: u32,
    window: Window,
    /// Each lap run so far.
    laps: Vec<LapNoise>,
}

impl Race {
    pub fn new(after: u32, window: Window) -> Self {
        Self {
            after,
            window,
            laps: Vec::with_capacity(LAPS.len()),
        }
    }

    /// The next lap, None once every lap has run.
    pub fn next(&self) -> Option<Lap> {
        let i = self.laps.len();
        LAPS.get(i).map(|&entrant| Lap {
            entrant,
            repeat: i % 2 == 1,
        })
    }

    pub fn record(&mut self, lap: LapNoise) {
        self.laps.push(lap);
    }

    /// The verdict, once every lap has run: `future_learning` is the share of
    /// the passes left in which the guide learns, `won_before` whether plain
    /// path tracing won the race before.
    pub fn verdict(&self, future_learning: f64, won_before: bool) -> RaceRecord {
        let of = |who: Entrant| {
            let laps = LAPS.iter().zip(&self.laps).filter(move |(&e, _)| e == who);
            let seconds = laps
                .clone()
                .map(|(_, l)| l.seconds)
                .fold(f64::INFINITY, f64::min);
            let n = laps.clone().count().max(1) as f64;
            (seconds, laps.map(|(_, l)| l.deviation).sum::<f64>() / n)
        };
        let (plain_seconds, plain_deviation) = of(Entrant::Plain);
        let (guide_seconds, guide_deviation) = of(Entrant::Guide);
        let guide_future_seconds = future_seconds(guide_seconds, &self.window, future_learning);
        let ratio = |plain: f64, guide: f64| {
            plain * plain_seconds / (guide * guide_future_seconds).max(1e-30)
        };
        let plain_over_guide = ratio(plain_deviation, guide_deviation);
        // Each pair is one plain lap and one guided lap on the same numbers.
        let pairs: Vec<(LapNoise, LapNoise)> = LAPS
            .chunks(2)
            .zip(self.laps.chunks(2))
            .map(|(entrants, laps)| {
                let lap = |who: Entrant| {
                    entrants
                        .iter()
                        .zip(laps)
                        .find(|(&e, _)| e == who)
                        .map_or(LapNoise::default(), |(_, l)| *l)
                };
                (lap(Entrant::Plain), lap(Entrant::Guide))
            })
            .collect();
        let plain_over_guide_pairs: Vec<f64> = pairs
            .iter()
            .map(|(p, g)| ratio(p.deviation, g.deviation))
            .collect();
        let guided: Vec<LapNoise> = pairs.iter().map(|(_, g)| *g).collect();
        let image = image_mean(&guided);
        let plain_missed_pairs: Vec<bool> =
            pairs.iter().map(|(p, _)| p.missed_light(image)).collect();
        // The pooled ratio lies between the pairs' (the seconds are shared),
        // so winning both pairs wins it too.
        let plain_wins = plain_over_guide_pairs
            .iter()
            .zip(&plain_missed_pairs)
            .all(|(r, &missed)| r * MARGIN < 1.0 && !missed);
        RaceRecord {
            after: self.after,
            plain_deviation,
            guide_deviation,
            plain_seconds,
            guide_seconds,
            guide_future_seconds,
            plain_over_guide,
            plain_over_guide_pairs,
            plain_missed_pairs,
            plain_wins,
            stands_back: won_before && plain_wins,
        }
    }
}

/// Seconds per guided pass to come: a pass that learns nothing
/// (`frozen`), plus what learning added per pass in `window`, scaled from
/// the share of its passes that learned to `future_learning`.
fn future_seconds(frozen: f64, window: &Window, future_learning: f64) -> f64 {
    if window.passes == 0 || window.learning == 0 {
        return frozen;
    }
    let per_pass = window.seconds / window.passes as f64;
    let learned = window.learning as f64 / window.passes as f64;
    frozen + (per_pass - frozen).max(0.0) * future_learning / learned
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Laps whose means agree with the reference's.
    fn race(laps: [(f64, f64); 4], window: Window) -> Race {
        race_with_means(laps.map(|(s, d)| (s, d, 1.0)), window)
    }

    /// Laps of (seconds, deviation, mean), each of 10^4 samples of variance
    /// 1; the reference's mean 1, its variance 10^-4.
    fn race_with_means(laps: [(f64, f64, f64); 4], window: Window) -> Race {
        race_with_variances(laps, 1.0, 1e-4, window)
    }

    /// The same with each sample's `variance` and the reference's own.
    fn race_with_variances(
        laps: [(f64, f64, f64); 4],
        variance: f64,
        reference: f64,
        window: Window,
    ) -> Race {
        let mut r = Race::new(8, window);
        for (i, (seconds, deviation, mean)) in laps.into_iter().enumerate() {
            let lap = r.next().expect("four laps");
            assert_eq!(lap.repeat, i % 2 == 1);
            let n = 1e4;
            let totals = [mean * n, (variance + mean * mean) * n, n, n * n * reference];
            r.record(LapNoise::new(seconds, deviation, n, totals));
        }
        assert_eq!(r.next(), None);
        r
    }

    #[test]
    fn a_guide_that_halves_the_noise_at_twice_the_time_stays() {
        // Plain: 1 ms, deviation 1; guide: 2 ms, deviation 0.5 -> even.
        let r = race(
            [(1e-3, 1.0), (2e-3, 0.5), (1e-3, 1.0), (2e-3, 0.5)],
            Window::default(),
        );
        let v = r.verdict(0.0, true);
        assert!((v.plain_over_guide - 1.0).abs() < 1e-9);
        assert!(!v.plain_wins && !v.stands_back);
    }

    #[test]
    fn a_guide_that_costs_time_and_cuts_no_noise_stands_back() {
        let r = race(
            [(1e-3, 1.0), (1.5e-3, 1.0), (1.4e-3, 1.0), (1.2e-3, 1.0)],
            Window::default(),
        );
        let v = r.verdict(0.0, true);
        // The faster lap of each: 1 ms against 1.4 ms.
        assert_eq!(v.plain_seconds, 1e-3);
        assert_eq!(v.guide_seconds, 1.4e-3);
        assert!((v.plain_over_guide - 1.0 / 1.4).abs() < 1e-9);
        assert!(v.plain_wins && v.stands_back);
        // One race won is not enough.
        let first = r.verdict(0.0, false);
        assert!(first.plain_wins && !first.stands_back);
    }

    #[test]
    fn plain_laps_that_missed_light_do_not_win() {
        // Plain path tracing's noise looks a hundredth of the guide's, but
        // its second lap's mean falls 0.15 short of the image's, where the
        // standard error of their difference is 0.012: it missed light.
        let laps = |second: f64| {
            [
                (1e-3, 0.01, 1.0),
                (2e-3, 1.0, 1.0),
                (2e-3, 1.0, 1.0),
                (1e-3, 0.01, second),
            ]
        };
        let v = race_with_means(laps(0.85), Window::default()).verdict(0.0, true);
        assert!(v.plain_over_guide_pairs.iter().all(|r| r * MARGIN < 1.0));
        assert_eq!(v.plain_missed_pairs, [false, true]);
        assert!(!v.plain_wins && !v.stands_back);
        // Short by less than a tenth of the light, or by 2.4 standard errors
        // (every lap's variance 30, the reference's 2.8e-3), it wins.
        assert!(
            race_with_means(laps(0.91), Window::default())
                .verdict(0.0, true)
                .stands_back
        );
        let v = race_with_variances(laps(0.85), 30.0, 2.8e-3, Window::default()).verdict(0.0, true);
        assert_eq!(v.plain_missed_pairs, [false, false]);
        // A plain lap above the reference missed nothing.
        let v = race_with_means(laps(1.5), Window::default()).verdict(0.0, true);
        assert_eq!(v.plain_missed_pairs, [false, false]);
    }

    #[test]
    fn a_spike_in_one_pair_of_laps_does_not_stand_the_guide_back() {
        // The guide halves the noise at 1.5x the time, but a spike common to
        // both entrants swells the second pair: pooled, plain path tracing
        // would win (cost 0.77x); in the first pair the guide wins.
        let r = race(
            [(1e-3, 1.0), (1.5e-3, 0.5), (1.5e-3, 6.0), (1e-3, 6.5)],
            Window::default(),
        );
        let v = r.verdict(0.0, true);
        assert!(v.plain_over_guide * MARGIN < 1.0);
        assert_eq!(v.plain_over_guide_pairs.len(), 2);
        assert!((v.plain_over_guide_pairs[0] - 1.0 / 0.75).abs() < 1e-9);
        assert!(!v.plain_wins && !v.stands_back);
        // Where plain path tracing wins both pairs, it wins.
        let r = race(
            [(1e-3, 1.0), (1.5e-3, 1.0), (1.5e-3, 6.0), (1e-3, 6.5)],
            Window::default(),
        );
        assert!(r.verdict(0.0, true).stands_back);
    }

    #[test]
    fn learning_to_come_adds_to_the_guides_time() {
        // Before the race every pass learned at 3 ms; a pass that learns
        // nothing takes 2 ms; half the passes to come learn: 2.5 ms.
        let w = Window {
            seconds: 24e-3,
            passes: 8,
            learning: 8,
        };
        assert!((future_seconds(2e-3, &w, 0.5) - 2.5e-3).abs() < 1e-12);
        assert!((future_seconds(2e-3, &w, 0.0) - 2e-3).abs() < 1e-12);
        // A window that learned nothing tells nothing of learning's cost.
        assert_eq!(future_seconds(2e-3, &Window::default(), 1.0), 2e-3);
        let r = race([(1e-3, 1.0), (2e-3, 0.6), (1e-3, 1.0), (2e-3, 0.6)], w);
        assert!(!r.verdict(0.0, true).plain_wins);
        assert!((r.verdict(1.0, true).guide_future_seconds - 3e-3).abs() < 1e-12);
    }
}
