"""OpenSCENARIO parameters: `$name` references and `${expression}` arithmetic resolved against the
ParameterDeclarations in scope (the file's, then a catalog entry's with its ParameterAssignments), evaluated
over a parsed syntax tree of numbers, parameters, `pi`, + - * / % ** and a few functions; never executed."""

from __future__ import annotations

import ast
import math
import operator
from pathlib import Path

from garage_exp.core.errors import GarageError



_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
        ast.Mod: operator.mod, ast.Pow: operator.pow, ast.USub: operator.neg, ast.UAdd: operator.pos}
_FUNCS = {"sqrt": math.sqrt, "sin": math.sin, "cos": math.cos, "tan": math.tan, "abs": abs, "min": min,
          "max": max, "round": round, "floor": math.floor, "ceil": math.ceil, "pow": pow}


def _evaluate(text: str, params: dict) -> float:
    """An OpenSCENARIO expression (`${$a*2 + pi}`) over the parameters; ValueError when it is not one."""

    def ev(node):
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return node.value
        if isinstance(node, ast.Name):
            if node.id == "pi":
                return math.pi
            if node.id.startswith("P_") and node.id[2:] in params:
                return float(params[node.id[2:]])
            raise ValueError(f"unknown name {node.id.removeprefix('P_')}")
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
            return _OPS[type(node.op)](ev(node.operand))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _FUNCS:
            return _FUNCS[node.func.id](*[ev(a) for a in node.args])
        raise ValueError("not an arithmetic expression")

    return float(ev(ast.parse(text.replace("$", "P_"), mode="eval")))


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
        except (ValueError, ZeroDivisionError, SyntaxError, TypeError) as exc:
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
