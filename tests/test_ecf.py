"""Prophesee's HDF5 event files: the ECF kernel against the naive decoder, Metavision-style files read back."""

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import evtools
from evtools._kernels.ecf import INCONSISTENT, TOO_MANY, TRUNCATED, decode_ecf
from evtools.events import EVENT_DTYPE, record_words
from evtools.formats import FormatError
from tests.helpers import assert_clean_error, read_all, run
from tests.naive import ecf_decode_naive, ecf_encode_naive, write_metavision_h5


@st.composite
def _events(draw, max_size=600):
    """Time-ordered (t, x, y, p): runs of equal times, rows and polarities, neighbouring columns (the codec's
    masks), steps from 0 to 2^40 us, times from 0 to 2^50 us."""
    n = draw(st.integers(1, max_size))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    steps = rng.choice([0, 0, 0, 0, 1, 2, 14, 15, 16, 255, 4096, 1 << 20, 1 << 40], size=n)
    t = draw(st.integers(0, 1 << 50)) + np.cumsum(steps) - steps[0]
    y = np.where(rng.random(n) < 0.8, rng.integers(0, 2048), rng.integers(0, 2048, n))
    x = rng.integers(0, 2048, n)
    neighbours = rng.random(n) < 0.5
    x[1:][neighbours[1:]] = np.minimum(x[:-1][neighbours[1:]] + rng.integers(1, 7, int(neighbours[1:].sum())), 2047)
    p = np.where(rng.random(n) < 0.9, 1, rng.integers(0, 2, n))
    return list(zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()))


def _decode(block: bytes, capacity: int):
    out = np.empty(capacity, EVENT_DTYPE)
    out.view(np.uint8)[:] = 0xAB  # every byte of a record must be written
    n = decode_ecf(np.frombuffer(block, np.uint8), record_words(out))
    if n < 0:
        return n
    raw = out[:n].view(np.uint8).reshape(-1, 16)
    assert not raw[:, 13:].any() and np.isin(raw[:, 12], (0, 1)).all()
    return list(zip(out["t"][:n].tolist(), out["x"][:n].tolist(), out["y"][:n].tolist(),
                    out["p"][:n].astype(int).tolist()))


@settings(max_examples=80, deadline=None)
@given(_events(), st.sampled_from([0, 1, 2]))
def test_the_kernel_decodes_every_block_mode_as_the_naive_decoder(events, mode):
    block = ecf_encode_naive(events, mode)
    assert ecf_decode_naive(block) == events  # the naive encoder and decoder agree
    assert _decode(block, len(events)) == events
    assert _decode(block, len(events) - 1) == TOO_MANY
    for cut in sorted({0, 4, 11, 12, len(block) // 3, len(block) // 2, len(block) - 1}):
        assert _decode(block[:cut], len(events)) == TRUNCATED  # every byte of a block is needed


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 300), st.sampled_from([0, 1, 2]), st.binary(min_size=0, max_size=400),
       st.integers(1, 400))
@example(5, 0, bytes([0x05]) + bytes(20), 10)  # a run of 5 times is all five: then rows, columns
@example(3, 0, bytes([0x05]) + bytes(20), 10)  # a run past the count: inconsistent
def test_the_kernel_reads_garbage_as_the_naive_decoder_or_refuses_it(count, mode, body, capacity):
    """Random bytes after a header and a time origin: the kernel gives the naive decoder's events (times as int64)
    or the error the naive decoder raises for them, never more events than asked and never a crash."""
    block = ((count << 2) | (2 if mode == 2 else 0) | (1 if mode == 1 else 0)).to_bytes(4, "little") + bytes(8) + body
    result = _decode(block, capacity)
    try:
        expected = ecf_decode_naive(block)
    except ValueError as error:
        assert result == {"truncated": TRUNCATED, "inconsistent": INCONSISTENT}[str(error)] or (
            count > capacity and result == TOO_MANY)
        return
    if count > capacity:
        assert result == TOO_MANY
    else:
        wrapped = [((t + (1 << 63)) % (1 << 64) - (1 << 63), x, y, p) for t, x, y, p in expected]
        assert result == wrapped


@settings(max_examples=40, deadline=None)
@given(_events(max_size=3000), st.integers(0, 2**32 - 1), st.sampled_from([16384, 1000, 7]),
       st.sampled_from([0.0, 0.3]), st.booleans(), st.integers(1, 5000))
def test_metavision_files_read_as_written(tmp_path_factory, events, seed, chunk, raw_chunks, pad_last, chunk_events):
    """A file laid out as Metavision writes one (ECF chunks in every mode, some chunks stored unfiltered, the last
    one partial, or whole and padded as HDF5's filter writes it) reads back as its events, in any chunk size and
    whole, with the sensor size of its attributes."""
    path = tmp_path_factory.mktemp("ecf") / "recording.hdf5"
    write_metavision_h5(path, events, 2048, 2048, seed, chunk=chunk, raw_chunks=raw_chunks, pad_last=pad_last)
    info, read = read_all(path, chunk_events=chunk_events, check=False)  # (times from 0 to 2^50 + 2^40 steps)
    assert (info.width, info.height, info.metadata["layout"], info.metadata["ecf"]) == (2048, 2048, "prophesee",
                                                                                       True)
    assert list(zip(read["t"].tolist(), read["x"].tolist(), read["y"].tolist(), read["p"].astype(int).tolist())) \
        == events
    whole = evtools.read(path, check=False)[0]
    assert np.array_equal(whole, read)


def test_the_real_recordings_read_back_from_metavision_files(tmp_path):
    """The Gen4.1 and DVXplorer recordings written as Metavision HDF5 files read back as the recordings, and the
    command line takes them (info, convert)."""
    from tests.conftest import data_file

    for name, size in (("gen41_sample.evt3.raw", (1280, 720)), ("dvxplorer_sample.aedat4", (320, 240))):
        events, _ = evtools.read(data_file(name))
        path = tmp_path / f"{name}.hdf5"
        write_metavision_h5(path, list(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(),
                                           events["p"].astype(int).tolist())), *size, seed=1)
        read, info = evtools.read(path)
        assert (info.width, info.height) == size
        assert np.array_equal(read, events)
    out = tmp_path / "out.aedat4"
    run("convert", path, "-o", out)
    assert np.array_equal(evtools.read(out)[0], events)


def test_damaged_chunks_are_refused_naming_the_file_and_the_chunk(tmp_path):
    import h5py

    events = [(t, t % 300, t % 200, t % 2) for t in range(40)]
    path = tmp_path / "damaged.hdf5"
    write_metavision_h5(path, events, 320, 240, seed=0, chunk=16)
    with h5py.File(path, "r+") as f:
        dataset = f["CD/events"]
        _, stored = dataset.id.read_direct_chunk((16,))
        dataset.id.write_direct_chunk((16,), stored[:len(stored) - 3], 0)
    assert_clean_error(run("info", path, check=False), "damaged.hdf5",
                       "the ECF chunk of CD/events at event 16 ends before its events do")
    with h5py.File(path, "r+") as f:
        f["CD/events"].id.write_direct_chunk((16,), ecf_encode_naive(events[16:30], 0), 0)
    with pytest.raises(FormatError, match=r"damaged\.hdf5: the ECF chunk of CD/events at event 16 holds 14 events"):
        read_all(path)
    with h5py.File(path, "r+") as f:  # a stored size no 16 events take (HDF5 allocates it before reading it)
        f["CD/events"].id.write_direct_chunk((16,), bytes(32 * 16 + 65), 0)
    with pytest.raises(FormatError, match=r"damaged\.hdf5: the chunk of CD/events at event 16 is stored in 577 bytes, "
                                          r"more than any 16 events take"):
        read_all(path)


def test_an_unfiltered_prophesee_file_is_read_through_h5py(tmp_path):
    import h5py

    records = np.zeros(5, np.dtype({"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"],
                                    "offsets": [0, 2, 4, 8], "itemsize": 16}))
    records["x"], records["y"], records["p"], records["t"] = [1, 2, 3, 4, 5], [5, 4, 3, 2, 1], [1, 0, 1, 1, 0], \
        [10, 11, 12, 13, 14]
    path = tmp_path / "plain.hdf5"
    with h5py.File(path, "w") as f:
        f.attrs["geometry"] = "640x480"
        f.create_dataset("CD/events", data=records, compression="gzip")
    info, read = read_all(path, chunk_events=2)
    assert (info.width, info.height, info.metadata["ecf"]) == (640, 480, False)
    assert read["x"].tolist() == [1, 2, 3, 4, 5] and read["p"].tolist() == [True, False, True, True, False]


@pytest.mark.parametrize("name", ["version", "format"])
def test_a_damaged_attribute_type_is_refused_before_hdf5_reads_it(tmp_path, name):
    """Issue 37 item 6, found by mutating the attribute headers of a Metavision file: one bit field byte of a
    variable-length string attribute's type turns it into a variable-length sequence, and reading that crashed the
    HDF5 library (SIGSEGV, plain h5py too). Its type is checked before its value is read: one line, exit 1."""
    path = tmp_path / "damaged.hdf5"
    write_metavision_h5(path, [(t, t % 300, t % 200, t % 2) for t in range(40)], 320, 240, seed=0, chunk=16)
    data = bytearray(path.read_bytes())
    at = data.index(name.encode() + b"\0")
    message = at + (len(name) + 8) // 8 * 8  # the type follows the name, padded to 8 bytes
    assert data[message] & 0x0F == 9 and data[message] >> 4 == 1, "not a variable-length string type"
    data[message + 1] = 0xC9  # its class bits: a sequence of a type HDF5 then reads from the damage
    path.write_bytes(bytes(data))
    assert_clean_error(run("info", path, check=False), "damaged.hdf5", f"attribute '{name}'", "a damaged file?")


def test_every_damage_to_the_attribute_headers_and_the_global_heap_is_read_or_refused(tmp_path):
    """Every byte of the root's two attribute messages and of the global heap holding their strings set to three
    values (the fuzz that found the crash above and two hangs: a collection or object size that HDF5 then loops
    on, deaf to signals, issue 37 item 6): each mutant opens or is refused with FormatError, in one child process
    that must neither crash nor hang."""
    path = tmp_path / "seed.hdf5"
    write_metavision_h5(path, [(t, t % 300, t % 200, t % 2) for t in range(40)], 320, 240, seed=0, chunk=16)
    data = path.read_bytes()
    heap = data.index(b"GCOL")
    spans = [(data.index(b"version\0") - 16, data.index(b"format\0") + 48, (0xFF, 0x01, 0xC9)),
             (heap, heap + 96, (0xFF, 0x01, 0x20))]
    mutants = []
    for start, end, values in spans:
        for at in range(start, end):
            for mutated in {value if value in (0xFF, 0xC9) else data[at] ^ value for value in values} - {data[at]}:
                mutant = tmp_path / f"m{len(mutants)}.hdf5"
                mutant.write_bytes(data[:at] + bytes([mutated]) + data[at + 1:])
                mutants.append(str(mutant))
    child = ("import sys, evtools\nfrom evtools.formats import FormatError\nread = refused = 0\n"
             "for path in sys.argv[1:]:\n    try:\n        evtools.open(path).close()\n        read += 1\n"
             "    except FormatError:\n        refused += 1\nprint(read, refused)\n")
    result = subprocess.run([sys.executable, "-c", child, *mutants], capture_output=True, timeout=120)
    assert result.returncode == 0, result.stderr.decode()[-2000:]
    read, refused = map(int, result.stdout.split())
    assert read + refused == len(mutants) > 600 and refused > 0
