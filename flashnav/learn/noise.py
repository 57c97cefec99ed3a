"""Temporally correlated collection noise: per-env, per-action sequences with a 1/f^beta power spectrum.

White noise (beta 0, the paper and the references) draws every step's exploration independently, so a
robot that must keep turning for 40 steps to face a goal behind it is pushed left and right in turn and
rarely completes the manoeuvre while exploring. Coloured noise keeps the draw's sign for longer:
beta 1 is pink, beta 2 red (Brownian-like); each step's draw is still N(0, 1) in distribution, so the
policy's Gaussian (its mean, spread and log-density) is unchanged - only successive draws are correlated
(Eberhard et al., "Pink Noise Is All You Need: Colored Noise Exploration in Deep Reinforcement
Learning", ICLR 2023). ``algo.noise_color`` sets beta; docs/learners.md S14.

Sequences are drawn by the Timmer-Koenig method: complex Gaussian Fourier coefficients with amplitudes
``f^(-beta/2)``, the mean component left out, an inverse real FFT, and the expected standard deviation
divided out, so a draw has unit variance on average over sequences. All envs read the same
step of their own sequence; every ``steps`` vector steps the whole block is drawn afresh (one
generation per block, no per-env bookkeeping, no host synchronisation).
"""

from __future__ import annotations

import dataclasses
import math

import torch

#: Length of one block of coloured sequences, in vector steps (longer than the robots' 200-step horizon, so
#: a sequence's slowest component spans a whole episode).
NOISE_STEPS = 256


def powerlaw_scales(beta: float, steps: int) -> torch.Tensor:
    """Fourier amplitudes ``[steps // 2 + 1]`` of a 1/f^beta sequence of ``steps`` samples (float64):
    ``f^(-beta/2)`` at the rFFT frequencies (the zero frequency, whose component is left out, held at 1/steps)."""
    freqs = torch.fft.rfftfreq(steps, dtype=torch.float64)
    freqs[0] = 1.0 / steps
    return freqs.pow(-beta / 2.0)


def powerlaw_noise(shape: tuple[int, ...], beta: float, steps: int, gen: torch.Generator,
                   device: torch.device | str) -> torch.Tensor:
    """``shape + (steps,)`` float32 sequences with power spectrum ~ 1/f^beta along the last axis, each with
    zero mean, unit variance in expectation (beta 0: white, N(0, 1) samples but for the removed mean)."""
    if steps < 2:
        raise ValueError(f"coloured noise needs sequences of at least 2 steps, got {steps}")
    scales = powerlaw_scales(beta, steps)
    # expected variance of the inverse FFT below, (2/n)^2 (sum of s_k^2 over 0 < k < n/2 + s_(n/2)^2 / 2): the
    # mean component is left out (zero), the Nyquist one (even n) is real with variance 2 s^2
    weights = scales.clone()
    weights[0] = 0.0
    if steps % 2 == 0:
        weights[-1] = weights[-1] / math.sqrt(2.0)
    sigma = 2.0 * math.sqrt(float(weights.pow(2).sum())) / steps
    scales = scales.to(device=device, dtype=torch.float32)
    real, imag = (torch.randn((*shape, 2, scales.numel()), generator=gen, device=device) * scales).unbind(-2)
    real, imag = real.clone(), imag.clone()
    real[..., 0] = 0.0
    imag[..., 0] = 0.0
    if steps % 2 == 0:
        real[..., -1] = real[..., -1] * math.sqrt(2.0)
        imag[..., -1] = 0.0
    return torch.fft.irfft(torch.complex(real, imag), n=steps) / sigma


@dataclasses.dataclass
class ColoredNoise:
    """Collection noise state: ``block [N, A, steps]`` (each env's and action's sequence) and ``step``, the
    position of the next draw in it. Checkpointed with the learner (``common.state_to_dict``)."""

    beta: float
    block: torch.Tensor
    step: int = 0

    @classmethod
    def create(cls, beta: float, num_envs: int, action_dim: int, gen: torch.Generator,
               device: torch.device | str, steps: int = NOISE_STEPS) -> ColoredNoise:
        return cls(beta, powerlaw_noise((num_envs, action_dim), beta, steps, gen, device))

    def draw(self, gen: torch.Generator) -> torch.Tensor:
        """The next step's noise ``[N, A]``; a fresh block (from ``gen``) once the current one is used up."""
        if self.step >= self.block.shape[-1]:
            self.block = powerlaw_noise(tuple(self.block.shape[:-1]), self.beta, self.block.shape[-1], gen,
                                        self.block.device)
            self.step = 0
        out = self.block[..., self.step]
        self.step += 1
        return out
