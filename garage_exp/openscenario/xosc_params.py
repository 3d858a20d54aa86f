"""OpenSCENARIO parameters: `$name` references and `${expression}` arithmetic resolved against the
ParameterDeclarations in scope (the file's, then a catalog entry's with its ParameterAssignments).

An expression is the standard's grammar (OpenSCENARIO 1.2, "Expressions"): numbers, `$name` parameters,
`true`/`false`, parentheses, unary `-` and `not`, `**`, `* / %`, `+ -`, comparisons (`== != < <= > >=`), `and`,
`or`, and the functions round, floor, ceil, sqrt, pow, sin, cos, tan, asin, acos, atan, sign, abs, max, min (plus
`pi`, which files in the wild use). It is parsed into Python's syntax tree and evaluated node by node over floats
(never executed); anything else, an unknown name, a division by zero, a value out of a function's domain or beyond
a double (`${10.0**400}`) is one line naming the expression.
"""

from __future__ import annotations

import ast
import math
import operator
from pathlib import Path

from garage_exp.core.errors import GarageError

MAX_EXPRESSION = 1000  # characters: an expression is a line of arithmetic, not a program


def _round(x: float) -> float:
    """Half away from zero, as C's round (Python's rounds half to even)."""
    return math.copysign(math.floor(abs(x) + 0.5), x)


def _sign(x: float) -> float:
    return (x > 0) - (x < 0)


_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Mod: math.fmod, ast.Pow: math.pow}  # % as C's fmod (the dividend's sign), as simulators compute it
_COMPARE = {ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
            ast.Gt: operator.gt, ast.GtE: operator.ge}
# name -> (function, number of arguments; None: one or more)
_FUNCS = {"round": (_round, 1), "floor": (math.floor, 1), "ceil": (math.ceil, 1), "sqrt": (math.sqrt, 1),
          "pow": (math.pow, 2), "sin": (math.sin, 1), "cos": (math.cos, 1), "tan": (math.tan, 1),
          "asin": (math.asin, 1), "acos": (math.acos, 1), "atan": (math.atan, 1), "sign": (_sign, 1),
          "abs": (abs, 1), "max": (max, None), "min": (min, None)}
_WORDS = {"pi": math.pi, "true": True, "false": False}


def _number(value) -> float | bool:
    """A parameter's value inside an expression: a number, or a boolean parameter's true/false."""
    if isinstance(value, (bool, float, int)):
        return value
    text = str(value).strip()
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None


def _evaluate(text: str, params: dict) -> float | bool:
    """An OpenSCENARIO expression (`${$a*2 + atan(1)}`) over the parameters; ValueError when it is not one or has
    no value (a division by zero, out of a function's domain, beyond a double)."""
    if len(text) > MAX_EXPRESSION:
        raise ValueError(f"longer than {MAX_EXPRESSION} characters")

    def num(node) -> float:
        value = ev(node)
        return float(value)

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and type(node.value) in (int, float):
            return float(node.value)  # floats throughout: `10**400` overflows instead of growing an integer
        if isinstance(node, ast.Name):
            if node.id in _WORDS:
                return _WORDS[node.id]
            if node.id.startswith("P_") and node.id[2:] in params:
                return _number(params[node.id[2:]])
            raise ValueError(f"unknown name {node.id.removeprefix('P_')!r}")
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            return _BINARY[type(node.op)](num(node.left), num(node.right))
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return -num(node.operand)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            return not ev(node.operand)
        if isinstance(node, ast.BoolOp):
            values = [bool(ev(v)) for v in node.values]
            return all(values) if isinstance(node.op, ast.And) else any(values)
        if isinstance(node, ast.Compare) and all(type(op) in _COMPARE for op in node.ops):
            left, out = num(node.left), True
            for op, right in zip(node.ops, node.comparators):
                right = num(right)
                out, left = out and _COMPARE[type(op)](left, right), right
            return out
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _FUNCS \
                and not node.keywords:
            function, arity = _FUNCS[node.func.id]
            if (arity is None and not node.args) or (arity is not None and len(node.args) != arity):
                raise ValueError(f"{node.func.id}() takes {arity or 'one or more'} argument(s), "
                                 f"got {len(node.args)}")
            return float(function(*[num(a) for a in node.args]))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            raise ValueError(f"no function {node.func.id}() in OpenSCENARIO's expressions "
                             f"({', '.join(_FUNCS)})")
        raise ValueError("not an OpenSCENARIO expression (numbers, $parameters, + - * / % **, comparisons, "
                         "not and or, functions)")

    try:
        value = ev(ast.parse(text.strip().replace("$", "P_"), mode="eval"))
    except SyntaxError:
        raise ValueError("not an OpenSCENARIO expression (a syntax error)") from None
    except OverflowError:
        raise ValueError("its value is beyond a double's range") from None
    except ZeroDivisionError:
        raise ValueError("a division by zero") from None
    except RecursionError:
        raise ValueError("nested too deeply") from None
    except (ValueError, TypeError) as exc:  # math's domain errors ("math domain error"), ours above
        why = str(exc)
        raise ValueError("a value outside its function's domain" if why == "math domain error" else why) from None
    if not isinstance(value, bool) and not math.isfinite(value):
        raise ValueError("its value is beyond a double's range")
    return value


class Values:
    """Attribute values with `$name` and `${expression}` resolved against the parameters in scope."""

    def __init__(self, path: Path, tree):
        self.path, self.tree = path, tree
        self.scopes: list[dict] = [{}]

    def where(self, element) -> str:
        return f"{self.path}: {self.tree.getpath(element)}" if element is not None else str(self.path)

    def declare(self, block, assigned: dict | None = None) -> dict:
        """A ParameterDeclarations block's values (later ones may use earlier ones), with `assigned` winning."""
        scope = dict(self.scopes[-1])
        assigned = assigned or {}
        for decl in (block.findall("ParameterDeclaration") if block is not None else []):
            name = decl.get("name")
            scope[name] = assigned[name] if name in assigned else self._resolve(decl.get("value"), scope, decl)
        for name, value in assigned.items():
            scope.setdefault(name, value)
        return scope

    def _resolve(self, raw, scope: dict, element):
        if raw is None:
            return None
        text = raw.strip()
        try:
            if text.startswith("${") and text.endswith("}"):
                return _evaluate(text[2:-1], scope)
            if text.startswith("$"):
                return scope[text[1:]]
        except KeyError:
            raise GarageError(f"no parameter {text[1:]!r}", self.where(element)) from None
        except ValueError as exc:
            raise GarageError(f"cannot evaluate {text!r}: {exc}", self.where(element)) from None
        return text

    def get(self, element, attr: str, default=None):
        value = self._resolve(element.get(attr), self.scopes[-1], element)
        return default if value is None else value

    def num(self, element, attr: str, default: float | None = None) -> float:
        value = self.get(element, attr)
        if value is None:
            if default is None:
                raise GarageError(f"no {attr}", self.where(element))
            return default
        try:
            return float(value)
        except ValueError:
            raise GarageError(f"{attr}={value!r} is not a number", self.where(element)) from None
