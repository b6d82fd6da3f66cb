"""Loops over modules written out before numba compiles (numba cannot loop over modules).

`@kernel` over `@unrolled`: in the function's source, a loop `for t in LIST:` whose LIST names
a tuple of modules (a global of the function's module, e.g. terms.ENERGY_TERMS) is written
out once per module, `t` standing for that module. Inside, what the module decides is decided
there: an `if` (or a part of an `and`/`or`) whose test reads only modules and constants, and
`getattr(x, <a name known from the module>)`, which becomes `x.name`. What is left is plain
code, compiled as if it were written in the function's own file at its own line (the kernel
cache finds it there); the list is read when the module is imported.
"""
from __future__ import annotations

import ast
import copy
import inspect
import textwrap
import types

_UNKNOWN = object()


def unrolled(function):
    """`function` with its loops over tuples of modules written out (module docstring)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(function)))
    ast.increment_lineno(tree, function.__code__.co_firstlineno - 1)
    definition = tree.body[0]
    definition.decorator_list = []
    local = {a.arg for a in definition.args.args} | {
        n.id for n in ast.walk(definition)
        if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)}
    writer = _Writer(function.__globals__, local)
    definition.body = writer.statements(definition.body, {})
    namespace = {}
    exec(compile(ast.fix_missing_locations(tree), inspect.getfile(function), 'exec'),
         function.__globals__, namespace)
    written = namespace[function.__name__]
    written.__doc__ = function.__doc__
    return written


class _Writer:
    def __init__(self, globals_, local):
        self.globals, self.local = globals_, local

    def value(self, node, bound):
        """The node's value if it reads only modules, constants and loop modules, else _UNKNOWN."""
        names = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
        if names & (self.local - bound.keys()):
            return _UNKNOWN
        try:
            code = compile(ast.Expression(node), '<unrolled>', 'eval')
            return eval(code, self.globals, dict(bound))
        except Exception:
            return _UNKNOWN

    def statements(self, body, bound):
        out = []
        for node in body:
            if isinstance(node, ast.For) and isinstance(node.target, ast.Name) and not node.orelse:
                modules = self.value(node.iter, bound)
                if isinstance(modules, tuple) and modules and all(
                        isinstance(m, types.ModuleType) for m in modules):
                    for module in modules:
                        alias = self.bind(module)
                        name = node.target.id
                        body = self.statements(copy.deepcopy(node.body), {**bound, name: module})
                        out += [_Rename(name, alias).visit(n) for n in body]
                    continue
            if isinstance(node, ast.If) and bound:
                test = self.condition(node.test, bound)
                if test is True or test is False:
                    out += self.statements(node.body if test else node.orelse, bound)
                    continue
                node.test = test
                node.body = self.statements(node.body, bound) or [ast.Pass()]
                node.orelse = self.statements(node.orelse, bound)
                out.append(node)
                continue
            out.append(self.expressions(node, bound) if bound else node)
        return out

    def condition(self, test, bound):
        """True/False when decided by the modules, else the test with the decided parts gone."""
        if isinstance(test, ast.BoolOp):
            decisive = isinstance(test.op, ast.Or)          # the value that ends an or / an and
            left = []
            for part in test.values:
                part = self.condition(part, bound)
                if part is decisive:
                    return decisive
                if part is not (not decisive):
                    left.append(part)
            if not left:
                return not decisive
            return left[0] if len(left) == 1 else ast.BoolOp(op=test.op, values=left)
        value = self.value(test, bound)
        return bool(value) if value is not _UNKNOWN else self.expressions(test, bound)

    def expressions(self, node, bound):
        writer = self

        class Getattr(ast.NodeTransformer):
            def visit_Call(self, call):
                self.generic_visit(call)
                if (isinstance(call.func, ast.Name) and call.func.id == 'getattr'
                        and len(call.args) == 2):
                    name = writer.value(call.args[1], bound)
                    if isinstance(name, str):
                        attribute = ast.Attribute(call.args[0], name, ast.Load())
                        return ast.copy_location(attribute, call)
                return call
        return Getattr().visit(node)

    def bind(self, module) -> str:
        """The global name the written code calls `module` by (its own, added if missing)."""
        alias = module.__name__.rsplit('.', 1)[1]
        if self.globals.setdefault(alias, module) is not module:
            raise NameError(f'{alias} names something else than {module.__name__}')
        return alias


class _Rename(ast.NodeTransformer):
    def __init__(self, old, new):
        self.old, self.new = old, new

    def visit_Name(self, node):
        if node.id != self.old:
            return node
        return ast.copy_location(ast.Name(self.new, node.ctx), node)
