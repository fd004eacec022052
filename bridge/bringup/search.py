"""Find the field of unknown ids that follows a known quantity: every start bit, length (1 to
32 bits), byte order and sign of each id's payloads, fitted against a reference.

Each field is fitted as ``reference ≈ scale * raw + offset`` by least squares and ranked by R²;
counters, checksums, flags and shifted variants never win, and of fields sharing a bit only the
best is told.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bridge.bringup.columns import Array, Bytes, id_text

#: Frames per id that the search looks at, at the most (sampled evenly beyond).
MAX_ROWS = 4000
#: Longest field searched, bits.
MAX_LENGTH = 32
#: A field that steps by one amount (not 0) in this share of its frames is a counter.
COUNTER_SHARE = 0.8
#: A field whose median step is over this share of its range is noise (a checksum).
NOISE_STEP = 0.25
#: A field's lowest bit flips at least this share of the most its bits flip: a smooth quantity's
#: lowest bits flip most.
LOW_BIT_SHARE = 0.5
#: Relative difference of 1 - R² within which two fits are equal (the same values).
_TIE = 1e-7

Floats = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Reference:
    """The known quantity: its name, unit, and values at log times (ns, sorted)."""

    name: str
    unit: str
    t: Array
    value: Floats


@dataclass(frozen=True)
class Field:
    """A field of an id's payload: where it lies and how its raw value is read."""

    bus: str
    key: int
    #: bit of its least significant bit (bit i = byte i // 8, bit i % 8)
    lsb: int
    length: int
    big_endian: bool
    signed: bool

    @property
    def start_bit(self) -> int:
        """The DBC start bit: the least significant bit (little-endian) or the most significant
        (big-endian, DBC's numbering)."""
        if not self.big_endian:
            return self.lsb
        bits = self.bits()
        return bits[-1]

    def bits(self) -> list[int]:
        """Its bits, least significant first."""
        if not self.big_endian:
            return list(range(self.lsb, self.lsb + self.length))
        out, bit = [], self.lsb
        for _ in range(self.length):
            out.append(bit)
            bit = bit - 15 if bit % 8 == 7 else bit + 1
        return out

    def describe(self) -> str:
        order = "big-endian" if self.big_endian else "little-endian"
        sign = "signed" if self.signed else "unsigned"
        return (f"{self.bus} {id_text(self.key)} start bit {self.start_bit}, {self.length} bits, "
                f"{order} {sign}")


@dataclass(frozen=True)
class Candidate:
    """A field fitted to the reference."""

    field: Field
    scale: float
    offset: float
    r2: float
    #: RMS of what the fit leaves, in the reference's unit
    rms: float
    frames: int
    #: the raw values' range in the frames looked at
    raw_min: int
    raw_max: int


@dataclass
class Search:
    """The ranked candidates and what was refused, and why."""

    candidates: list[Candidate]
    ids: int
    frames: int
    refused: dict[str, int] = field(default_factory=dict)


def field_values(payload: Bytes, f: Field) -> Array:
    """The raw values of a field in each payload row (int64; signed where the field is)."""
    bits = np.unpackbits(payload, axis=1, bitorder="little")
    value = np.zeros(len(payload), dtype=np.int64)
    for i, bit in enumerate(f.bits()):
        if bit < bits.shape[1]:
            value |= bits[:, bit].astype(np.int64) << i
    if f.signed:
        value = np.where(value >= 1 << (f.length - 1), value - (1 << f.length), value)
    return value


def _sample(n: int) -> Array:
    if n <= MAX_ROWS:
        return np.arange(n)
    sampled: Array = np.linspace(0, n - 1, MAX_ROWS).round().astype(np.int64)
    return sampled


@dataclass
class _Fits:
    """Every field of one id fitted (parallel arrays)."""

    lsb: list[int] = field(default_factory=list)
    length: list[int] = field(default_factory=list)
    big: list[bool] = field(default_factory=list)
    signed: list[bool] = field(default_factory=list)
    r2: list[Floats] = field(default_factory=list)


def _words(payload: Bytes, at: int) -> tuple[npt.NDArray[np.uint64], npt.NDArray[np.uint64]]:
    """Bytes ``at`` to ``at + 8`` of each row as a little-endian and a big-endian word."""
    window = np.zeros((len(payload), 8), dtype=np.uint8)
    part = payload[:, at:at + 8]
    window[:, :part.shape[1]] = part
    window = np.ascontiguousarray(window)
    little = window.view("<u8").ravel().astype(np.uint64)
    big = window.view(">u8").ravel().astype(np.uint64)
    return little, big


def _r2(values: Floats, centred_ref: Floats, ref_ss: float) -> Floats:
    centred = values - values.mean(axis=0)
    ss = np.einsum("ij,ij->j", centred, centred)
    cross = centred_ref @ centred
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.where(ss > 0, cross * cross / (ss * ref_ss), -1.0)
    return np.asarray(r2, dtype=np.float64)


def _fit_all(payload: Bytes, width_bits: int, changing: npt.NDArray[np.bool_],
             centred_ref: Floats, ref_ss: float) -> _Fits:
    """R² of every field of the payloads whose lowest bit changes (see the module)."""
    fits = _Fits()
    n_bytes = payload.shape[1]
    starts = range(0, max(1, n_bytes - 4), 4) if n_bytes > 8 else range(1)
    seen: set[tuple[int, int, bool]] = set()
    lengths_all = np.arange(1, MAX_LENGTH + 1, dtype=np.uint64)
    masks_all = (np.uint64(1) << lengths_all) - np.uint64(1)
    for at in starts:
        little, big = _words(payload, at)
        for big_endian, word in ((False, little), (True, big)):
            for p in range(64):
                if big_endian:
                    byte, bit = at + 7 - p // 8, p % 8
                else:
                    byte, bit = at + p // 8, p % 8
                lsb = byte * 8 + bit
                if lsb >= width_bits or not changing[lsb]:
                    continue
                longest = min(MAX_LENGTH, 64 - p)
                lengths = np.arange(1, longest + 1)
                if big_endian:  # within one byte it is the little-endian field
                    lengths = lengths[(p % 8) + lengths > 8]
                # a field that runs past the payload is a longer name for a shorter one
                inside = [int(n) for n in lengths if _top_byte(at, p, int(n), big_endian)
                          < n_bytes]
                lengths = np.asarray([n for n in inside if (lsb, n, big_endian) not in seen],
                                     dtype=np.int64)
                if not len(lengths):
                    continue
                seen.update((lsb, int(n), big_endian) for n in lengths)
                shifted = word >> np.uint64(p)
                raw = shifted[:, None] & masks_all[lengths - 1][None, :]
                values = raw.astype(np.float64)
                fits.r2.append(_r2(values, centred_ref, ref_ss))
                fits.lsb += [lsb] * len(lengths)
                fits.length += lengths.tolist()
                fits.big += [big_endian] * len(lengths)
                fits.signed += [False] * len(lengths)
                wide = lengths >= 2
                if wide.any():
                    half = (2.0 ** (lengths[wide] - 1))[None, :]
                    signed_values = values[:, wide] - (values[:, wide] >= half) * 2 * half
                    fits.r2.append(_r2(signed_values, centred_ref, ref_ss))
                    fits.lsb += [lsb] * int(wide.sum())
                    fits.length += lengths[wide].tolist()
                    fits.big += [big_endian] * int(wide.sum())
                    fits.signed += [True] * int(wide.sum())
    return fits


def _top_byte(at: int, p: int, length: int, big_endian: bool) -> int:
    """The byte of a field's most significant bit (``p``: its lowest bit in the word at
    byte ``at``)."""
    top = p + length - 1
    return at + 7 - top // 8 if big_endian else at + top // 8


def _refusal(values: Array, length: int, signed: bool, ref_values: int) -> str | None:
    """Why a field cannot be the quantity (see the module), or None."""
    distinct = np.unique(values)
    if len(distinct) <= 2 and ref_values > 2:
        return "flags (two values at most)"
    steps = np.diff(values)
    if not len(steps):
        return None
    wrapped = np.mod(steps, 1 << length)
    modes, counts = np.unique(wrapped, return_counts=True)
    top = int(np.argmax(counts))
    if modes[top] != 0 and counts[top] >= COUNTER_SHARE * len(steps):
        return "counters"
    spread = float(values.max() - values.min())
    if spread > 0 and float(np.median(np.abs(steps))) > NOISE_STEP * spread:
        return "checksums and noise (jump across their range between frames)"
    return None


def search(samples: dict[tuple[str, int], tuple[Array, Bytes]], reference: Reference, *,
           top: int = 5) -> Search:
    """Rank the fields of each id's ``(times, payloads)`` against ``reference``.

    The reference is interpolated to each frame's time. Constant fields, shifted or padded
    variants of a field, counters (:data:`COUNTER_SHARE`), checksums and other jumping fields
    (:data:`NOISE_STEP`), flags (unless the reference has two values) and fields that swallow a
    lower neighbour's bits (:data:`LOW_BIT_SHARE`) never win; of fields sharing a bit, only the
    best is told. An id with more than :data:`MAX_ROWS` frames in the reference's span is sampled
    evenly.
    """
    ref_values = len(np.unique(reference.value))
    found: list[Candidate] = []
    refused: dict[str, int] = {}
    frames = 0
    searched = 0
    for (bus, key), (t, payload) in sorted(samples.items()):
        inside = (t >= reference.t[0]) & (t <= reference.t[-1])
        t, payload = t[inside], payload[inside]
        if len(t) < 3 or not payload.shape[1]:
            continue
        rows = _sample(len(t))
        t, payload = t[rows], payload[rows]
        frames += len(t)
        searched += 1
        ref = np.interp(t.astype(np.float64), reference.t.astype(np.float64), reference.value)
        centred_ref = ref - ref.mean()
        ref_ss = float(centred_ref @ centred_ref)
        if ref_ss <= 0:
            continue
        changing = np.unpackbits(np.bitwise_or.reduce(payload[1:] ^ payload[:-1], axis=0),
                                 bitorder="little").astype(bool)
        fits = _fit_all(payload, payload.shape[1] * 8, changing, centred_ref, ref_ss)
        if not fits.r2:
            continue
        found += _best_of_id(bus, key, payload, ref, fits, ref_values, refused, top)
    found.sort(key=lambda c: -c.r2)
    return Search(found[:top], searched, frames, refused)


def _best_of_id(bus: str, key: int, payload: Bytes, ref: Floats, fits: _Fits, ref_values: int,
                refused: dict[str, int], top: int) -> list[Candidate]:
    """The id's best fields, one per place (see the module), at most ``top``."""
    r2 = np.concatenate(fits.r2)
    order = np.argsort(-r2, kind="stable").tolist()
    rates = np.unpackbits(payload[1:] ^ payload[:-1], axis=1, bitorder="little").sum(axis=0)
    family: dict[tuple[int, bool], list[int]] = {}
    for i in order:
        family.setdefault((fits.lsb[i], fits.big[i]), []).append(i)
    taken: list[Candidate] = []
    used: set[int] = set()
    done: set[tuple[int, bool]] = set()
    for i in order:
        if len(taken) >= top or r2[i] <= 0:
            break
        place = (fits.lsb[i], fits.big[i])
        if place in done:
            continue
        f = Field(bus, key, fits.lsb[i], fits.length[i], fits.big[i], fits.signed[i])
        if used.intersection(f.bits()):
            continue
        # the fits as good as this one at the same lowest bit: the same values, named anew
        limit = (1 - r2[i]) * (1 + _TIE) + 1e-12
        ties = [j for j in family[place] if 1 - r2[j] <= limit]
        best = min(ties, key=lambda j: (fits.length[j] % 8 != 0, fits.signed[j],
                                        fits.length[j]))
        f = Field(bus, key, fits.lsb[best], fits.length[best], fits.big[best],
                  fits.signed[best])
        if used.intersection(f.bits()):
            continue
        values = field_values(payload, f)
        why = _refusal(values, f.length, f.signed, ref_values)
        if why is None and rates[f.lsb] < LOW_BIT_SHARE * max(rates[b] for b in f.bits()):
            why = "fields whose lowest bits are another's (flip less than the bits above them)"
        if why is not None:
            refused[why] = refused.get(why, 0) + 1
            done.add(place)
            continue
        taken.append(_fitted(f, values, ref, float(r2[best])))
        used.update(f.bits())
    return taken


def _fitted(f: Field, values: Array, ref: Floats, r2: float) -> Candidate:
    x = values.astype(np.float64)
    xc = x - x.mean()
    scale = float((xc @ (ref - ref.mean())) / (xc @ xc))
    offset = float(ref.mean() - scale * x.mean())
    residual = ref - (scale * x + offset)
    return Candidate(f, scale, offset, r2, float(np.sqrt(np.mean(residual ** 2))), len(values),
                     int(values.min()), int(values.max()))
