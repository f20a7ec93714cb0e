"""The ``pymb.map/1`` types, byte orders and value states, as one table.

Everything that knows how wide a type is, whether it is signed, which keys it
takes and what its raw range is reads it here: the loader, the Python
reference codec and the compiled C table.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "BIT_TABLES",
    "FLOAT_TYPES",
    "INTEGER_TYPES",
    "ORDER_NAMES",
    "REGISTER_TABLES",
    "SF_RANGE",
    "STATES",
    "SUNSSF_NOT_IMPLEMENTED",
    "TABLES",
    "TABLE_FUNCTIONS",
    "TYPES",
    "TypeInfo",
    "normalize_order",
    "permutation",
]

#: The four Modbus tables, as the file names them.
TABLES = ("coil", "discrete", "holding", "input")
#: Each table's read function code: FC 01 coils, 02 discrete, 03 holding, 04 input.
TABLE_FUNCTIONS = {t: i + 1 for i, t in enumerate(TABLES)}
#: Tables of 16-bit registers (the other two hold bits).
REGISTER_TABLES = frozenset({"holding", "input"})
#: Tables of single bits (FC 01, 02): limits and costs count bits, not registers.
BIT_TABLES = frozenset(("coil", "discrete"))


@dataclass(frozen=True)
class TypeInfo:
    """How one type is laid out: registers it takes (0: from ``count``),
    whether it is signed, and its family (``int``, ``float``, ``sm``, ``bit``,
    ``bits``, ``bool``, ``string``, ``raw``, ``half`` for the 8-bit halves)."""

    name: str
    registers: int
    signed: bool
    family: str

    @property
    def bits(self) -> int:
        """Bits of the raw value (8 for the halves, 16 per register otherwise)."""
        return 8 if self.family == "half" else 16 * self.registers

    def raw_range(self) -> tuple[int, int]:
        """Smallest and largest raw integer of an integer type."""
        n = self.bits
        if self.signed:
            return -(1 << (n - 1)), (1 << (n - 1)) - 1
        if self.family == "sm":
            return -0x7FFF, 0x7FFF
        return 0, (1 << n) - 1


def _t(name: str, registers: int, signed: bool, family: str) -> tuple[str, TypeInfo]:
    return name, TypeInfo(name, registers, signed, family)


#: Every type of the format (contract section 3).
TYPES: dict[str, TypeInfo] = dict([
    _t("bool", 1, False, "bool"),
    _t("bit", 1, False, "bit"),
    _t("bits", 1, False, "bits"),
    _t("u8_hi", 1, False, "half"),
    _t("u8_lo", 1, False, "half"),
    _t("i8_hi", 1, True, "half"),
    _t("i8_lo", 1, True, "half"),
    _t("u16", 1, False, "int"),
    _t("i16", 1, True, "int"),
    _t("u32", 2, False, "int"),
    _t("i32", 2, True, "int"),
    _t("u64", 4, False, "int"),
    _t("i64", 4, True, "int"),
    _t("f16", 1, True, "float"),
    _t("f32", 2, True, "float"),
    _t("f64", 4, True, "float"),
    _t("sm16", 1, False, "sm"),
    _t("sunssf", 1, True, "int"),
    _t("string", 0, False, "string"),
    _t("raw", 0, False, "raw"),
])

#: Types whose value is an integer (scale/offset make it a float).
INTEGER_TYPES = frozenset(n for n, t in TYPES.items() if t.family in ("int", "half", "sm", "bits"))
FLOAT_TYPES = frozenset(n for n, t in TYPES.items() if t.family == "float")

#: The named orders (section 3): ABCD big-endian high word first, CDAB words
#: reversed, BADC bytes swapped in each register, DCBA both.
ORDER_NAMES = ("ABCD", "CDAB", "BADC", "DCBA")
_LETTERS = "ABCDEFGH"

#: State names by code, the codes the C decoder writes. 0..6 are fixed;
#: a map's own marker names get codes from 16 up (``Map.state_names``).
STATES = ("value", "offline", "no_sensor", "unsupported", "not_read", "nan", "invalid_text",
          "no_scale")

#: A ``sunssf`` point (SunSpec's scale factor: an int16 exponent of 10) that
#: reads 0x8000 is not implemented: this marker is every ``sunssf``'s own.
SUNSSF_NOT_IMPLEMENTED = 0x8000
#: The scale factors a ``scale_from`` point accepts (SunSpec's range): any
#: other, or a not-implemented one, gives no value (the state ``no_scale``).
SF_RANGE = (-10, 10)


def normalize_order(order: str, nbytes: int) -> str | None:
    """The explicit byte permutation (``"CDAB"``, ``"GHEFCDAB"``, ``"BA"``)
    that ``order`` means for a value of ``nbytes`` bytes (2, 4 or 8), or None
    when ``order`` is neither a named order nor a permutation of that many
    letters."""
    letters = _LETTERS[:nbytes]
    regs = [letters[i:i + 2] for i in range(0, nbytes, 2)]
    if order == "ABCD":
        return letters
    if order == "CDAB":
        return "".join(reversed(regs))
    if order == "BADC":
        return "".join(r[::-1] for r in regs)
    if order == "DCBA":
        return letters[::-1]
    if len(order) == nbytes and sorted(order) == list(letters):
        return order
    return None


def permutation(order: str) -> tuple[int, ...]:
    """For each byte of the value, most significant (A) first, its position
    in the bytes as they arrive: ``permutation("CDAB") == (2, 3, 0, 1)``."""
    return tuple(order.index(_LETTERS[k]) for k in range(len(order)))
