"""Temporally correlated collection noise: per-env, per-action sequences with a 1/f^beta power spectrum.

White noise (beta 0, the paper and the references) draws every step's exploration independently, so a
robot that must keep turning for 40 steps to face a goal behind it is pushed left and right in turn and
rarely completes the manoeuvre while exploring. Coloured noise keeps the draw's sign for longer:
beta 1 is pink, beta 2 red (Brownian-like); each step's draw is still N(0, 1) in distribution, so the
policy's Gaussian (its mean, spread and log-density) is unchanged - only successive draws are correlated
(Eberhard et al., "Pink Noise Is All You Need: Colored Noise Exploration in Deep Reinforcement
Learning", ICLR 2023). ``algo.noise_color`` sets beta, for every action or per action (e.g. pink on the
TurtleBot2's turn command only, white on its forward speed: ``[0, 1]``); docs/learners.md S14.

Sequences are drawn by the Timmer-Koenig method: complex Gaussian Fourier coefficients with amplitudes
``f^(-beta/2)``, the mean component left out, an inverse real FFT, and the expected standard deviation
divided out, so a draw has unit variance on average over sequences. All envs read the same
step of their own sequence; every ``steps`` vector steps the whole block is drawn afresh (one
generation per block, no per-env bookkeeping, no host synchronisation).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import torch

#: Length of one block of coloured sequences, in vector steps (longer than the robots' 200-step horizon, so
#: a sequence's slowest component spans a whole episode).
NOISE_STEPS = 256


def exponents(beta: float | Sequence[float]) -> tuple[float, ...]:
    """``algo.noise_color`` as a tuple: ``(beta,)`` for one exponent, else one per action."""
    return (float(beta),) if isinstance(beta, (int, float)) else tuple(float(b) for b in beta)


def powerlaw_scales(beta: float, steps: int) -> torch.Tensor:
    """Fourier amplitudes ``[steps // 2 + 1]`` of a 1/f^beta sequence of ``steps`` samples (float64):
    ``f^(-beta/2)`` at the rFFT frequencies (the zero frequency, whose component is left out, held at 1/steps)."""
    freqs = torch.fft.rfftfreq(steps, dtype=torch.float64)
    freqs[0] = 1.0 / steps
    return freqs.pow(-beta / 2.0)


def expected_std(scales: torch.Tensor, steps: int) -> float:
    """Standard deviation, in expectation, of a sample of the inverse FFT of Gaussian coefficients with amplitudes
    ``scales`` (:func:`powerlaw_scales`): (2/n) sqrt(sum of s_k^2 over 0 < k < n/2 + s_(n/2)^2 / 2); the mean
    component is left out (zero), the Nyquist one (even n) is real with variance 2 s^2."""
    weights = scales.clone()
    weights[0] = 0.0
    if steps % 2 == 0:
        weights[-1] = weights[-1] / math.sqrt(2.0)
    return 2.0 * math.sqrt(float(weights.pow(2).sum())) / steps


def powerlaw_noise(shape: tuple[int, ...], beta: float | Sequence[float], steps: int, gen: torch.Generator,
                   device: torch.device | str) -> torch.Tensor:
    """``shape + (steps,)`` float32 sequences with power spectrum ~ 1/f^beta along the last axis, each with
    zero mean, unit variance in expectation (beta 0: white, N(0, 1) samples but for the removed mean).

    ``beta`` is one exponent for every sequence, or one per index of the last axis of ``shape`` (per action:
    ``shape = (envs, actions)``); the Gaussian draws are the same either way, only their amplitudes differ."""
    if steps < 2:
        raise ValueError(f"coloured noise needs sequences of at least 2 steps, got {steps}")
    betas = exponents(beta)
    if len(betas) != 1 and (not shape or len(betas) != shape[-1]):
        raise ValueError(f"{len(betas)} exponents beta {list(betas)} for sequences of shape {tuple(shape)}: give one, or one "
                         f"per index of the last axis ({shape[-1] if shape else 0})")
    per_beta = [powerlaw_scales(b, steps) for b in betas]
    sigma = torch.tensor([expected_std(s, steps) for s in per_beta], dtype=torch.float32, device=device)
    scales = torch.stack(per_beta).to(device=device, dtype=torch.float32)            # [B, F], B = 1 or shape[-1]
    draws = torch.randn((*shape, 2, scales.shape[-1]), generator=gen, device=device)  # [..., 2, F]
    real, imag = (draws * scales.unsqueeze(-2)).unbind(-2)
    real, imag = real.clone(), imag.clone()
    real[..., 0] = 0.0
    imag[..., 0] = 0.0
    if steps % 2 == 0:
        real[..., -1] = real[..., -1] * math.sqrt(2.0)
        imag[..., -1] = 0.0
    return torch.fft.irfft(torch.complex(real, imag), n=steps) / sigma.unsqueeze(-1)


@dataclasses.dataclass
class ColoredNoise:
    """Collection noise state: ``block [N, A, steps]`` (each env's and action's sequence) and ``step``, the
    position of the next draw in it, checkpointed with the learner (``common.state_to_dict``). ``beta``: the
    exponent, one for every action or one per action (a tuple: configuration, not state, so a checkpoint
    neither saves nor overrides it)."""

    beta: tuple[float, ...]
    block: torch.Tensor
    step: int = 0

    @classmethod
    def create(cls, beta: float | Sequence[float], num_envs: int, action_dim: int, gen: torch.Generator,
               device: torch.device | str, steps: int = NOISE_STEPS) -> ColoredNoise:
        betas = exponents(beta)
        return cls(betas, powerlaw_noise((num_envs, action_dim), betas, steps, gen, device))

    def draw(self, gen: torch.Generator) -> torch.Tensor:
        """The next step's noise ``[N, A]``; a fresh block (from ``gen``) once the current one is used up."""
        if self.step >= self.block.shape[-1]:
            self.block = powerlaw_noise(tuple(self.block.shape[:-1]), self.beta, self.block.shape[-1], gen,
                                        self.block.device)
            self.step = 0
        out = self.block[..., self.step]
        self.step += 1
        return out
