#include "core/diagnosis/segmentation.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "core/pipeline/impact_detector.hpp"
#include "core/pipeline/stream_processor.hpp"

namespace ridgewatch::diagnosis {

namespace {

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

/// 1. Onsets: the pipeline's detector with its trigger band centred on the rig's model f0 (+-15 %,
///    the pipeline's default width relative to 854 Hz).
std::vector<std::uint64_t> detect_onsets(std::span<const double> y, double fs, const model::RigParameters& rig) {
  const double f0 = rig.natural_frequency_hz();
  pipeline::PipelineConfig pc;
  pc.sample_rate_hz = fs;
  pc.detector.band_lo_hz = 0.85 * f0;
  pc.detector.band_hi_hz = std::min(1.15 * f0, 0.45 * fs);
  pc.analyzer.f_expected_hz = f0;
  pc.analyzer.band_rel = 0.3;
  pipeline::validate(pc);  // std::invalid_argument names the field
  pipeline::ImpactDetector det(pc.detector, fs, 1u << 12);
  det.restart(0);
  std::vector<std::uint64_t> onsets;
  for (std::size_t i = 0; i < y.size(); ++i) {
    det.push(static_cast<float>(y[i]));
    while (det.has_onset()) onsets.push_back(det.pop_onset());
  }
  det.finish();
  while (det.has_onset()) onsets.push_back(det.pop_onset());
  std::sort(onsets.begin(), onsets.end());
  return onsets;
}

/// 1b. Off-grid onsets: the cracked tooth meets once per revolution, so every true onset has a
///     neighbour a whole number of revolutions away. An onset whose spacings to both neighbours are
///     more than 10 % of a revolution off any whole number (a trigger on a noise burst or a carried
///     tail, seen at 3 % noise with dry friction: 12 ms early, its window cut and the true impact lost)
///     is dropped; the windows around it then see the next true onset instead.
void drop_off_grid_onsets(std::vector<std::uint64_t>& onsets) {
  if (onsets.size() < 3) return;
  std::vector<double> spacing;
  for (std::size_t k = 1; k < onsets.size(); ++k) spacing.push_back(static_cast<double>(onsets[k] - onsets[k - 1]));
  const double rev = median(spacing);
  auto on_grid = [&](std::uint64_t a, std::uint64_t b) {
    const double revs = static_cast<double>(b - a) / rev;
    return revs > 0.5 && std::abs(revs - std::round(revs)) <= 0.1;
  };
  std::vector<std::uint64_t> kept;
  for (std::size_t k = 0; k < onsets.size(); ++k) {
    const bool left = k > 0 && on_grid(onsets[k - 1], onsets[k]);
    const bool right = k + 1 < onsets.size() && on_grid(onsets[k], onsets[k + 1]);
    if (left || right) kept.push_back(onsets[k]);
  }
  if (kept.size() >= 2) onsets = std::move(kept);
}

/// 2.-4. Noise floor, spikes and dropouts (into seg.noise_sd, seg.spikes, seg.dropouts, seg.weight).
void noise_spikes_dropouts(std::span<const double> y, double fs, const std::vector<std::uint64_t>& onsets, Segmentation& seg) {
  const std::size_t n = y.size();
  // 2. Noise floor and spikes from the 4-neighbour cubic-interpolation residual
  //    r[n] = x[n] - (-x[n-2] + 4x[n-1] + 4x[n+1] - x[n+2]) / 6 (as the detector's spike stage): a
  //    sinusoid of θ rad/sample leaves θ^4/6 of its amplitude (2e-5 for 860 Hz at 51.2 kHz), white
  //    noise of sd σ leaves sd σ sqrt(70/36). So the noise floor between impacts is measured even
  //    with mesh lines, hum or a decaying tail present. Samples within [-0.5, +1] ms of an onset are
  //    skipped (the force pulse's kink leaves a few % of the amplitude there).
  std::vector<double> r(n, 0.0);
  std::vector<char> near_onset(n, 0);
  for (std::uint64_t o : onsets) {
    const auto a = static_cast<std::int64_t>(o) - static_cast<std::int64_t>(0.0005 * fs);
    const auto b = static_cast<std::int64_t>(o) + static_cast<std::int64_t>(0.001 * fs);
    for (std::int64_t k = std::max<std::int64_t>(0, a); k < std::min<std::int64_t>(static_cast<std::int64_t>(n), b); ++k)
      near_onset[static_cast<std::size_t>(k)] = 1;
  }
  std::vector<double> absr;
  for (std::size_t i = 2; i + 2 < n; ++i) {
    r[i] = y[i] - (-y[i - 2] + 4.0 * y[i - 1] + 4.0 * y[i + 1] - y[i + 2]) / 6.0;
    if (!near_onset[i]) absr.push_back(std::abs(r[i]));
  }
  double peak_all = 0.0;
  for (double v : y) peak_all = std::max(peak_all, std::abs(v));
  // MAD -> sd (Gaussian: MAD = 0.6745 sd), then the residual's gain sqrt(70/36). Floor: 1e-6 of the
  // record peak (float32 data carries ~6e-8 relative rounding noise; a noise-free simulation would
  // otherwise give a zero floor and an infinite excess).
  const double r_sd = median(absr) / 0.6745;
  seg.noise_sd = std::max(r_sd / std::sqrt(70.0 / 36.0), 1e-6 * peak_all);
  seg.noise_at_floor = r_sd / std::sqrt(70.0 / 36.0) < 1e-6 * peak_all;

  // 3. Spikes: |r| above 10 robust sd (a Gaussian sample exceeds that with p = 2e-23) and 8 times the
  //    residual 3-4 samples away (which a one-sample outlier does not touch, while any vibration
  //    raises r smoothly over many samples). The local maximum of |r| is the outlier itself.
  const double r_floor = std::max(r_sd, 1e-6 * peak_all);
  for (std::size_t i = 4; i + 4 < n; ++i) {
    if (near_onset[i]) continue;
    const double a = std::abs(r[i]);
    if (a < 10.0 * r_floor) continue;
    if (a < std::abs(r[i - 1]) || a < std::abs(r[i + 1])) continue;
    const double far = std::max({std::abs(r[i - 3]), std::abs(r[i + 3]), std::abs(r[i - 4]), std::abs(r[i + 4])});
    if (a < 8.0 * far) continue;
    seg.spikes.push_back(i);
    seg.weight[i] = 0.0;
  }
  // 4. Dropouts: runs of >= 4 identical samples (a lost vibrometer return or a stalled ADC holds the
  //    last value or zero; Gaussian noise at any level above the float32 rounding never repeats 4 times).
  for (std::size_t i = 0; i < n;) {
    std::size_t j = i + 1;
    while (j < n && y[j] == y[i]) ++j;
    if (j - i >= 4 && peak_all > 0.0) {
      seg.dropouts.push_back(i);
      seg.dropout_samples += j - i;
      for (std::size_t k = i; k < j; ++k) seg.weight[k] = 0.0;
    }
    i = j;
  }
}

/// Local revolution period at onset k (see the comment inside); 0 when fewer than 3 onsets are usable.
double local_period(const std::vector<std::uint64_t>& onsets, std::size_t k, double fs, double revolution_s) {
  // Local period: least-squares slope of onset time against revolution number over the onsets
  // within ±4 revolutions (±0.16 s at 1500 rpm; follows a speed ramp, smooths a faster fluctuation).
  // The detector's onsets scatter by a sample or more, so one spacing is off by ~0.1 % of 40 ms at
  // 25.6 kHz; that error in f_z turns the mesh-periodic terms 0.07 rad out of phase by the end of a
  // 20 ms window, 1-2x the 0.5 % noise power when the stiffness variation is strong (measured: held-out
  // excess 1.2 with the median of 4 spacings, 0.13 with ±2 revolutions, 0.001 with ±4). A spacing that
  // is not close to a whole number of revolutions (a mis-detected onset) ends the run; fewer than 3
  // onsets fall back to the median of up to 4 neighbouring spacings.
  double period = 0.0;
  {
    double n_pts = 0.0, sr = 0.0, st = 0.0, srr = 0.0, srt = 0.0;
    auto add = [&](double rev, std::uint64_t onset) {
      const double t = static_cast<double>(onset) / fs;
      n_pts += 1.0;
      sr += rev;
      st += t;
      srr += rev * rev;
      srt += rev * t;
    };
    add(0.0, onsets[k]);
    for (int dir : {-1, 1}) {
      double rev = 0.0;
      std::size_t j = k;
      while (true) {
        const std::size_t next = dir < 0 ? j - 1 : j + 1;
        if ((dir < 0 && j == 0) || next >= onsets.size()) break;
        const double revs = std::abs(static_cast<double>(onsets[next]) - static_cast<double>(onsets[j])) / fs / revolution_s;
        const double whole = std::round(revs);
        if (whole < 1.0 || std::abs(revs - whole) > 0.25) break;
        rev += dir * whole;
        if (std::abs(rev) > 4.0) break;
        add(rev, onsets[next]);
        j = next;
      }
    }
    const double d = n_pts * srr - sr * sr;
    if (n_pts >= 3.0 && d > 0.0) period = (n_pts * srt - sr * st) / d;
  }
  return period;
}

}  // namespace

Segmentation segment_recording(std::span<const double> y, double fs, const model::RigParameters& rig,
                               const SegmentationOptions& opt) {
  Segmentation seg;
  seg.sample_rate_hz = fs;
  const std::size_t n = y.size();
  seg.weight.assign(n, 1.0);

  std::vector<std::uint64_t> onsets = detect_onsets(y, fs, rig);
  drop_off_grid_onsets(onsets);
  noise_spikes_dropouts(y, fs, onsets, seg);

  // 5. Windows and the local revolution period (one impact per revolution).
  std::vector<double> gaps;
  for (std::size_t k = 1; k < onsets.size(); ++k) gaps.push_back(static_cast<double>(onsets[k] - onsets[k - 1]) / fs);
  seg.revolution_s = gaps.empty() ? 1.0 / rig.pinion_speed_hz() : median(gaps);
  const auto pre = static_cast<std::uint64_t>(std::llround(opt.pre_s * fs));
  for (std::size_t k = 0; k < onsets.size(); ++k) {
    if (onsets[k] < pre) continue;
    ImpactWindow w;
    w.begin = onsets[k] - pre;
    std::uint64_t end = onsets[k] + static_cast<std::uint64_t>(std::llround(opt.post_s * fs));
    if (k + 1 < onsets.size()) end = std::min(end, onsets[k + 1] - std::min(onsets[k + 1], pre));
    end = std::min<std::uint64_t>(end, n);
    if (end <= onsets[k] || static_cast<double>(end - onsets[k]) < opt.min_post_s * fs) continue;
    w.end = end;
    w.onset_s = static_cast<double>(onsets[k]) / fs;
    double period = local_period(onsets, k, fs, seg.revolution_s);
    if (period <= 0.0) {
      std::vector<double> local;
      for (std::size_t g = (k >= 2 ? k - 2 : 0); g < std::min(gaps.size(), k + 2); ++g) local.push_back(gaps[g]);
      period = local.empty() ? seg.revolution_s : median(local);
    }
    if (period > 1.5 * seg.revolution_s || period < 0.5 * seg.revolution_s) period = seg.revolution_s;
    w.mesh_hz = rig.pinion_teeth / period;
    if (!seg.windows.empty()) {
      const double spacing = w.onset_s - seg.windows.back().onset_s;
      if (spacing < 1.5 * seg.revolution_s) w.predecessor = static_cast<int>(seg.windows.size()) - 1;
    }
    seg.windows.push_back(w);
  }
  for (const auto& w : seg.windows)
    for (std::uint64_t i = w.begin; i < w.end; ++i)
      if (seg.weight[i] > 0.0) seg.peak = std::max(seg.peak, std::abs(y[i]));
  return seg;
}

}  // namespace ridgewatch::diagnosis

namespace ridgewatch::diagnosis {

Segmentation subset_windows(const Segmentation& seg, std::size_t max_windows) {
  const std::size_t groups = std::max<std::size_t>(1, max_windows / 4);
  if (seg.windows.size() <= groups * 4) return seg;
  Segmentation out = seg;
  out.windows.clear();
  const std::size_t stride = seg.windows.size() / groups;
  for (std::size_t g = 0; g < groups; ++g)
    for (std::size_t k = 0; k < 4 && g * stride + k < seg.windows.size(); ++k) {
      ImpactWindow w = seg.windows[g * stride + k];
      w.predecessor = (k == 0 || w.predecessor < 0) ? -1 : static_cast<int>(out.windows.size()) - 1;
      out.windows.push_back(w);
    }
  return out;
}

}  // namespace ridgewatch::diagnosis
