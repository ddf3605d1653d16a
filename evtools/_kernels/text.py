"""Text event files: one pass over a block of whole lines that splits the fields and reads the plain decimal numbers
(``-12``, ``0.003811``, ``1468939993.067416000``), compiled with numba.

numpy's text parser (``np.fromstring(..., sep=" ")``) costs ~180 ns a number and the field count of every line
three passes more: 10M events of an rpg ``events.txt`` took 8.3 s. This kernel hands back each number as an integer
mantissa and a count of decimals; the caller divides, which gives the correctly rounded double that numpy's parser
gives (Clinger's fast path: a mantissa below 2^53 and a power of ten up to 10^22 are both exact doubles, and one
IEEE division of exact operands is correctly rounded), so the events are the same. Anything else (an exponent,
``true``, ``nan``, more significant digits than a double holds exactly, an empty CSV field) is left to numpy's
parser and its error messages: the kernel says so and the caller falls back for that block.

References
----------
W. D. Clinger, "How to Read Floating Point Numbers Accurately", PLDI 1990 (the exact fast path).
"""

from __future__ import annotations

from evtools._kernels.jit import kernel

PARSED = 0
"""Every line parsed."""
WRONG_COUNT = 1
"""A line has another number of fields than the columns (the line's index in the block and its count returned)."""
OTHER_SYNTAX = 2
"""A field this kernel does not read exactly: numpy's parser takes the block."""

EXACT_MANTISSA = 1 << 53
"""A mantissa below this with decimals is an exact double, so its quotient by a power of ten is correctly rounded."""
MAX_DECIMALS = 22
"""10^22 is the largest exact power of ten in a double."""


@kernel
def parse_text(block, columns, csv, mantissas, decimals, row_lines, exact_column):  # pragma: no cover - compiled
    """Split a block of whole lines into ``columns`` numbers a line and read them.

    Parameters
    ----------
    block : ndarray of uint8
        Whole lines, each ending with ``\\n``.
    columns : int
        Fields a line must have.
    csv : bool
        Fields separated by commas (whitespace around a field ignored; a line empty or ``\\r`` alone is blank);
        otherwise by runs of bytes up to 32 (space, tab, ``\\r``; a line without a field is blank).
    mantissas, decimals : ndarray of int64, shape (lines, columns)
        Each number as ``mantissa / 10**decimals`` (trailing zeros of the decimals removed).
    row_lines : ndarray of int64, shape (lines,)
        The line (index in the block) of each row.
    exact_column : int
        A column read as an exact decimal whatever its mantissa (up to 18 digits: times in seconds, whose
        microseconds the caller makes of mantissa and decimals in integers); -1: none.

    Returns
    -------
    status : int
        PARSED, WRONG_COUNT or OTHER_SYNTAX.
    rows : int
        Rows written (PARSED).
    line, fields : int
        WRONG_COUNT: the first such line's index in the block and its field count.
    point : int
        1 when a field had a decimal point (numpy's integer parser would have refused the block).
    """
    n = block.shape[0]
    rows = 0
    line = 0
    point = 0
    i = 0
    while i < n:
        end = i
        while end < n and block[end] != 10:
            end += 1
        # the fields of block[i:end]
        if csv and (end == i or (end == i + 1 and block[i] == 13)):
            i = end + 1
            line += 1
            continue
        fields = 0
        j = i
        while True:
            # one field: skip the separators before it
            while j < end and block[j] <= 32:
                j += 1
            if j >= end and not csv:
                break
            start = j
            if csv:
                while j < end and block[j] != 44:
                    j += 1
                stop = j
                while stop > start and block[stop - 1] <= 32:
                    stop -= 1
            else:
                while j < end and block[j] > 32:
                    j += 1
                stop = j
            if fields < columns:
                # [+-]? digits* ('.' digits*)?, at least one digit; the decimals' trailing zeros dropped
                k = start
                negative = False
                if k < stop and (block[k] == 43 or block[k] == 45):
                    negative = block[k] == 45
                    k += 1
                mantissa = 0
                used = 0  # significant digits in the mantissa (from its first non-zero one)
                first = k
                while k < stop and 48 <= block[k] <= 57:
                    mantissa = mantissa * 10 + (block[k] - 48)
                    used += mantissa != 0
                    k += 1
                digits = k - first
                places = 0
                if k < stop and block[k] == 46:
                    point = 1
                    k += 1
                    first = k
                    while k < stop and 48 <= block[k] <= 57:
                        k += 1
                    digits += k - first
                    last = k
                    while last > first and block[last - 1] == 48:
                        last -= 1
                    for q in range(first, last):
                        mantissa = mantissa * 10 + (block[q] - 48)
                        used += mantissa != 0
                    places = last - first
                # 18 significant digits always fit in int64; beyond, numpy reads the field (and saturates as it does);
                # the exact column takes 19 where they fit (at most one wrap: negative)
                wide = used == 19 and fields == exact_column and mantissa >= 0
                if k != stop or digits == 0 or (used > 18 and not wide) or places > MAX_DECIMALS or \
                        (places > 0 and mantissa >= EXACT_MANTISSA and fields != exact_column):
                    return OTHER_SYNTAX, 0, line, 0, point
                mantissas[rows, fields] = -mantissa if negative else mantissa
                decimals[rows, fields] = places
            fields += 1
            if csv:
                if j >= end:
                    break
                j += 1  # the comma
        if fields != 0 or csv:
            if fields != columns:
                return WRONG_COUNT, 0, line, fields, point
            row_lines[rows] = line
            rows += 1
        i = end + 1
        line += 1
    return PARSED, rows, line, 0, point
