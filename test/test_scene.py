"""Scene loading: the packaged scenes load; malformed scenes fail with one clear error that
names the source and the field; mass properties match closed forms."""
import copy
import math
import time
import subprocess
import sys

import numpy as np
import pytest

from abd_joint_sim import Scene, SceneError, World, compile_scene
from abd_joint_sim.geometry import rpy_matrix
from abd_joint_sim.model import mass_properties
from abd_joint_sim.terms.damping import DAMPING_RATIO_MAX

from physics_helpers import SCENES, box, hinge_dict, scene_dict


@pytest.mark.slow
@pytest.mark.parametrize('name', sorted(p.stem for p in SCENES.glob('*.yaml')))
def test_packaged_scenes_load_and_step(name):
    w = World(Scene.from_yaml(SCENES / f'{name}.yaml'))
    w.step(2)
    assert np.all(np.isfinite(w.state.q)) and w.last_step.converged


def _mutate(path, value):
    d = hinge_dict()
    node = d
    *head, last = path
    for key in head:
        node = node[key]
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return d


DELETE = object()
NAN = float('nan')

# (id, path into the hinge scene, new value, field named in the message, words in the message)
BAD = [
    ('missing_dt', ('dt',), DELETE, '', "missing required key 'dt'"),
    ('zero_dt', ('dt',), 0.0, 'dt', 'must be > 0'),
    ('negative_dt', ('dt',), -0.01, 'dt', 'must be > 0'),
    ('string_dt', ('dt',), 'fast', 'dt', 'must be a number'),
    ('nan_dt', ('dt',), NAN, 'dt', 'must be finite'),
    ('gravity_len', ('gravity',), [0, -9.8], 'gravity', 'list of 3 numbers'),
    ('bad_integrator', ('integrator',), 'rk4', 'integrator', 'bdf1, bdf2'),
    ('unknown_top_key', ('solver',), {}, '', "unknown key(s) 'solver'"),
    ('no_bodies', ('bodies',), [], 'bodies', 'non-empty list'),
    ('negative_density', ('bodies', 1, 'density'), -5.0, 'bodies[1].density', 'must be > 0'),
    ('zero_density', ('bodies', 1, 'density'), 0, 'bodies[1].density', 'must be > 0'),
    ('zero_kappa', ('bodies', 1, 'kappa'), 0.0, 'bodies[1].kappa', 'must be > 0'),
    ('negative_box', ('bodies', 1, 'box'), [0.4, -0.4, 0.4], 'bodies[1].box[1]', 'must be > 0'),
    ('nan_position', ('bodies', 1, 'position'), [0.6, NAN, 0], 'bodies[1].position[1]', 'finite'),
    ('fixed_not_bool', ('bodies', 0, 'fixed'), 'yes please', 'bodies[0].fixed', 'true or false'),
    ('unknown_body_key', ('bodies', 1, 'colour'), 'red', 'bodies[1]', "unknown key(s) 'colour'"),
    ('duplicate_body', ('bodies', 1, 'name'), 'base', 'bodies[1].name', "duplicate name 'base'"),
    ('unknown_parent', ('joints', 0, 'parent'), 'ground', 'joints[0].parent', "unknown body 'ground'"),
    ('self_joint', ('joints', 0, 'parent'), 'arm', 'joints[0].child', 'to itself'),
    ('parent_list', ('joints', 0, 'parent'), ['base'], 'joints[0].parent', "must be a non-empty string, got ['base']"),
    ('child_mapping', ('joints', 0, 'child'), {'name': 'arm'}, 'joints[0].child', 'must be a non-empty string'),
    ('p0_equals_p1', ('joints', 0, 'p1'), [0.0, 0.0, -0.5], 'joints[0].p1', 'must differ from p0'),
    ('missing_p1', ('joints', 0, 'p1'), DELETE, 'joints[0]', "missing required key 'p1'"),
    ('zero_strength', ('joints', 0, 'strength_ratio'), 0.0, 'joints[0].strength_ratio', '> 0'),
    ('torque_not_number', ('joints', 0, 'external_torque', 'torque'), 'a lot',
     'joints[0].external_torque.torque', 'must be a number'),
    ('torque_nan', ('joints', 0, 'external_torque', 'torque'), NAN, 'joints[0].external_torque.torque', 'finite'),
    ('enabled_int', ('joints', 0, 'external_torque', 'enabled'), 1,
     'joints[0].external_torque.enabled', 'true or false'),
    ('torque_over_limit', ('joints', 0, 'external_torque'), {'torque': 10.0, 'effort_limit': 5.0},
     'joints[0].external_torque.torque', 'exceeds effort_limit'),
    ('prismatic_torque', ('joints', 0, 'type'), 'prismatic', 'joints[0].external_torque',
     'requires a revolute joint (UID 18)'),
    ('limit_inverted', ('joints', 0, 'limit'), {'lower': 1.0, 'upper': -1.0}, 'joints[0].limit', 'lower 1.0 > upper -1.0'),
    ('duplicate_joint', ('joints', 1), None, 'joints[1].name', "duplicate name 'hinge'"),
    ('two_shapes', ('bodies', 1, 'sphere'), 0.2, 'bodies[1]', 'exactly one of box'),
    ('bad_inertia', ('bodies', 1), {'name': 'arm', 'inertial': {'mass': 1.0, 'inertia': {'ixx': 1.0, 'iyy': 1.0, 'izz': 5.0}}},
     'bodies[1].inertial.inertia', 'not a physical inertia'),
    ('negative_mass', ('bodies', 1), {'name': 'arm', 'inertial': {'mass': -1.0, 'inertia': {'ixx': 1, 'iyy': 1, 'izz': 1}}},
     'bodies[1].inertial.mass', 'must be > 0'),
    ('newton_iterations_zero', ('newton',), {'max_iterations': 0}, 'newton.max_iterations', '>= 1'),
    ('rotation_limit_pi', ('newton',), {'max_step_rotation': 3.2}, 'newton.max_step_rotation', '< pi'),
    # Sane ranges: without them each of these would pass validation and then
    # fail deep inside the solver (LinAlgError, ZeroDivisionError, overflow) or hang.
    ('dt_tiny', ('dt',), 1e-300, 'dt', 'outside the supported range 1e-06 to 1 s'),
    ('dt_huge_int', ('dt',), 10 ** 400, 'dt', 'integer of 401 digits'),
    ('velocity_tol_huge', ('newton',), {'velocity_tol': 1e300}, 'newton.velocity_tol',
     'outside the supported range'),
    ('box_tiny', ('bodies', 1, 'box'), [1e-200, 0.4, 0.4], 'bodies[1].box[0]', 'outside the supported range'),
    ('density_huge', ('bodies', 1, 'density'), 1e30, 'bodies[1].density', 'kg/m^3'),
    ('kappa_huge', ('bodies', 1, 'kappa'), 1e300, 'bodies[1].kappa', 'outside the supported range'),
    ('position_far', ('bodies', 1, 'position'), [1e200, 0, 0], 'bodies[1].position[0]', '|value| <= 10000 m'),
    ('strength_tiny', ('joints', 0, 'strength_ratio'), 1e-300, 'joints[0].strength_ratio', 'supported range'),
    ('torque_huge', ('joints', 0, 'external_torque', 'torque'), 1e300,
     'joints[0].external_torque.torque', 'supported range'),
    ('damping_negative', ('joints', 0, 'damping'), -0.5, 'joints[0].damping', 'must be >= 0'),
    ('damping_nan', ('joints', 0, 'damping'), NAN, 'joints[0].damping', 'finite'),
    ('damping_huge', ('joints', 0, 'damping'), 1e300, 'joints[0].damping', '|value| <= 1e+09 N m s/rad'),
    ('substep_depth_11', ('newton',), {'max_substep_depth': 11}, 'newton.max_substep_depth', 'must be <= 10'),
    ('substep_depth_30', ('newton',), {'max_substep_depth': 30}, 'newton.max_substep_depth', 'must be <= 10'),
    ('init_outside_limit', ('joints', 0), {'name': 'hinge', 'parent': 'base', 'child': 'arm',
                                           'p0': [0, 0, -0.5], 'p1': [0, 0, 0.5], 'init_angle': -20.0,
                                           'limit': {'lower': -1.0, 'upper': 1.0}},
     'joints[0].init_angle', "outside the joint's limit [-1, 1]"),
    ('visual_kind_list', ('bodies', 1, 'visuals'), [{'kind': ['box']}], 'bodies[1].visuals[0].kind',
     "must be one of box, sphere, cylinder, mesh, got ['box']"),
]


@pytest.mark.parametrize('case', BAD, ids=[c[0] for c in BAD])
def test_malformed_scene_gets_one_clear_error(case):
    _, path, value, field, words = case
    if case[0] == 'duplicate_joint':
        d = hinge_dict()
        d['joints'].append(copy.deepcopy(d['joints'][0]))
    else:
        d = _mutate(path, value)
    with pytest.raises(SceneError) as err:
        Scene.from_dict(d, source='bad.yaml')
    msg = str(err.value)
    assert msg.startswith(f'bad.yaml: {field}: ' if field else 'bad.yaml: '), msg
    assert words in msg, msg
    assert '\n' not in msg


def test_yaml_syntax_error_names_file_and_line(tmp_path):
    p = tmp_path / 'broken.yaml'
    p.write_text('dt: 0.01\nbodies: [\n  {name: a\n')
    with pytest.raises(SceneError, match=r'broken.yaml: not valid YAML \(line \d+'):
        Scene.from_yaml(p)
    with pytest.raises(SceneError, match='cannot read scene file'):
        Scene.from_yaml(tmp_path / 'missing.yaml')


def test_yaml_floats_with_exponents_and_nan_are_read_as_numbers(tmp_path):
    text = (SCENES / 'hinge.yaml').read_text().replace('kappa: 1.0e8', 'kappa: 1e9', 1)
    p = tmp_path / 's.yaml'
    p.write_text(text)
    assert Scene.from_yaml(p).bodies[0].kappa == 1e9
    p.write_text(text.replace('dt: 0.01', 'dt: .nan'))
    with pytest.raises(SceneError, match='dt: must be finite'):
        Scene.from_yaml(p)


def test_box_sphere_cylinder_mass_properties():
    s = Scene.from_dict(dict(dt=0.01, bodies=[
        box('b', (0, 0, 0), (0.4, 0.2, 0.1)),
        dict(name='s', sphere=0.1, density=1000.0),
        dict(name='c', cylinder=dict(radius=0.1, length=0.5), density=1000.0)]))
    m, c, S, v, _ = mass_properties(s.bodies[0])
    assert m == pytest.approx(8.0) and S == pytest.approx(8.0 * np.diag([0.16, 0.04, 0.01]) / 12)
    m, c, S, v, _ = mass_properties(s.bodies[1])
    assert m == pytest.approx(1000 * 4 / 3 * math.pi * 1e-3)
    I_o = np.trace(S) * np.eye(3) - S
    assert I_o == pytest.approx(0.4 * m * 0.01 * np.eye(3))            # 2/5 m R^2
    m, c, S, v, _ = mass_properties(s.bodies[2])
    I_o = np.trace(S) * np.eye(3) - S
    assert np.diag(I_o) == pytest.approx([m * (3 * 0.01 + 0.25) / 12] * 2 + [m * 0.01 / 2])


def test_inertial_body_round_trips_its_rigid_inertia():
    I_cm = np.array([[0.3, 0.01, 0.0], [0.01, 0.2, 0.02], [0.0, 0.02, 0.4]])
    com = [0.1, -0.2, 0.05]
    s = Scene.from_dict(dict(dt=0.01, bodies=[dict(name='r', inertial=dict(mass=2.0, com=com, inertia=I_cm.tolist()))]))
    m, c, S, v, _ = mass_properties(s.bodies[0])
    I_o = np.trace(S) * np.eye(3) - S
    c = np.array(com)
    assert I_o - m * (c @ c * np.eye(3) - np.outer(c, c)) == pytest.approx(I_cm)
    M = compile_scene(s).body_M[0]
    assert M[0, 3:6] == pytest.approx(2.0 * c) and np.all(np.linalg.eigvalsh(M) > 0)


def test_rpy_is_urdf_convention():
    R = rpy_matrix((0.0, 0.0, math.pi / 2))          # yaw: x -> y
    assert R @ [1, 0, 0] == pytest.approx([0, 1, 0])
    R = rpy_matrix((math.pi / 2, 0.0, 0.0))          # roll: y -> z
    assert R @ [0, 1, 0] == pytest.approx([0, 0, 1])
    r, p, y = 0.3, -0.4, 1.2
    Rx = rpy_matrix((r, 0, 0)); Ry = rpy_matrix((0, p, 0)); Rz = rpy_matrix((0, 0, y))
    assert rpy_matrix((r, p, y)) == pytest.approx(Rz @ Ry @ Rx)


def test_anchor_order_is_the_same_on_both_bodies():
    """§9: both bodies store P0 then P1, so their raw axes agree."""
    d = hinge_dict()
    d['bodies'][1]['rpy'] = [0.3, 0.2, 0.1]
    m = compile_scene(Scene.from_dict(d))
    for side in (0, 1):
        b = (m.joint_parent[0], m.joint_child[0])[side]
        R = m.body_q0[b, 3:12].reshape(3, 3)
        p = m.body_q0[b, :3]
        assert R @ m.joint_anchor0[0, side] + p == pytest.approx([0, 0, -0.5])
        assert R @ m.joint_anchor1[0, side] + p == pytest.approx([0, 0, 0.5])


def test_scene_errors_are_clean_on_the_command_line(tmp_path):
    """Loading a bad scene from a script ends with the message, not a traceback."""
    p = tmp_path / 'bad.yaml'
    p.write_text('dt: -1\nbodies: []\n')
    code = ('import sys\nfrom abd_joint_sim import Scene, SceneError\n'
            'try:\n    Scene.from_yaml(sys.argv[1])\nexcept SceneError as e:\n    sys.exit(f"error: {e}")\n')
    r = subprocess.run([sys.executable, '-c', code, str(p)], capture_output=True, text=True)
    assert r.returncode == 1 and r.stderr.strip() == f'error: {p}: dt: must be > 0, got -1.0'


# -- the YAML loader's limits -------------------------------------------------------------

def _write(tmp_path, text, name='s.yaml'):
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def _one_line_error(path):
    with pytest.raises(SceneError) as err:
        Scene.from_yaml(path)
    msg = str(err.value)
    assert msg.startswith(f'{path}: ') and '\n' not in msg, msg
    return msg


def test_alias_bomb_fails_fast_with_bounded_memory(tmp_path):
    """Billion laughs: 1 KB of text, ~1e9 values expanded. Refused from the node graph,
    before anything expands it."""
    lines = ['a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]']
    for k in range(1, 10):
        lines.append(f'a{k}: &a{k} [' + ', '.join([f'*a{k - 1}'] * 10) + ']')
    lines.append('dt: 0.01\nbodies: *a9')
    p = _write(tmp_path, '\n'.join(lines) + '\n')
    assert p.stat().st_size < 1100
    import tracemalloc
    tracemalloc.start()
    t0 = time.monotonic()
    msg = _one_line_error(p)
    wall = time.monotonic() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert 'more than 100000 values once aliases (*name) are expanded, from 34 in the text' \
        in msg, msg
    assert wall < 10.0 and peak < 50e6, (wall, peak)


@pytest.mark.slow
def test_aliases_reused_many_times_in_a_large_file_are_fine():
    """The bound is relative to the text: 30 000 bodies sharing one anchored mapping (about
    330 000 values expanded, more than the absolute 100 000) load."""
    from abd_joint_sim.scene import load_yaml
    text = 'base: &b {box: [0.1, 0.1, 0.1], density: 1000.0}\nbodies:\n' + ''.join(
        f'  - {{<<: *b, name: b{k}}}\n' for k in range(30_000))
    assert len(load_yaml(text)['bodies']) == 30_000


def test_recursive_alias_and_deep_nesting_are_clear_errors(tmp_path):
    msg = _one_line_error(_write(tmp_path, 'dt: 0.01\nbodies: &b [*b]\n'))
    assert 'refers to a node that contains it' in msg, msg
    msg = _one_line_error(_write(tmp_path, 'dt: 0.01\nbodies: ' + '[' * 100_000 + '\n', 'deep.yaml'))
    assert 'nested deeper than 64 levels' in msg, msg


def test_anchors_and_merge_keys_still_work(tmp_path):
    text = (SCENES / 'hinge.yaml').read_text()
    text = text.replace('  - name: base\n', '  - &cube\n    name: base\n', 1)
    text = text.replace('  - name: arm\n    box: [0.4, 0.4, 0.4]\n    density: 1000.0\n'
                        '    kappa: 1.0e8\n', '  - <<: *cube\n    name: arm\n    fixed: false\n', 1)
    scene = Scene.from_yaml(_write(tmp_path, text))
    assert scene.bodies[1].name == 'arm' and scene.bodies[1].shape.size == (0.4, 0.4, 0.4)
    assert not scene.bodies[1].fixed


def test_file_size_and_encoding_named(tmp_path):
    msg = _one_line_error(_write(tmp_path, b'dt: 0.01\nname: caf\xe9\n'))
    assert 'is not UTF-8 text (byte 0xe9 at offset 18, line 2)' in msg, msg
    msg = _one_line_error(_write(tmp_path, 'dt: 0.01\n' + '#' * (8 << 20), 'big.yaml'))
    assert 'larger than 8388608 bytes' in msg, msg


def test_huge_integer_literal_is_a_field_error(tmp_path):
    text = (SCENES / 'hinge.yaml').read_text().replace('dt: 0.01', 'dt: 1' + '0' * 400)
    msg = _one_line_error(_write(tmp_path, text))
    assert ': dt: must be finite' in msg, msg
    text = (SCENES / 'hinge.yaml').read_text().replace('dt: 0.01', 'dt: 1' + '0' * 5000)
    msg = _one_line_error(_write(tmp_path, text, 'b.yaml'))
    assert 'not valid YAML' in msg, msg


def test_duplicate_key_names_the_key(tmp_path):
    text = (SCENES / 'hinge.yaml').read_text() + 'bodies: []\n'
    msg = _one_line_error(_write(tmp_path, text))
    assert "duplicate key 'bodies' (first at line" in msg and '(line 28, column 1)' in msg, msg


@pytest.mark.parametrize('literal', ['1:30', '0x10', '0o17', '1_000', '0b11'])
def test_yaml11_number_forms_are_not_numbers(tmp_path, literal):
    """YAML 1.1 reads 1:30 as 90 and 0x10 as 16; here they stay text and the field check
    names them (numbers are decimal)."""
    text = (SCENES / 'hinge.yaml').read_text().replace('dt: 0.01', f'dt: {literal}')
    msg = _one_line_error(_write(tmp_path, text))
    assert f": dt: must be a number, got '{literal}'" in msg, msg


def test_zero_width_limit_is_a_lock_any_init_angle():
    d = hinge_dict()
    d['joints'][0].update(init_angle=0.0, limit={'lower': 0.1, 'upper': 0.1})
    assert Scene.from_dict(d).joints[0].limit.lower == 0.1


def test_leading_zero_is_decimal_as_in_yaml12():
    from abd_joint_sim.scene import load_yaml
    assert load_yaml('a: 010\nb: -007.5\nc: 1e3') == {'a': 10, 'b': -7.5, 'c': 1000.0}


def test_yaml11_yes_is_not_a_boolean(tmp_path):
    text = (SCENES / 'hinge.yaml').read_text().replace('fixed: true', 'fixed: yes')
    msg = _one_line_error(_write(tmp_path, text))
    assert "bodies[0].fixed: must be true or false, got 'yes'" in msg, msg


def test_supported_range_corners_build_and_step():
    """The ends of the ranges are usable, not only accepted: the smallest and largest bodies
    at the extreme densities and stiffnesses build and take steps at both dt bounds."""
    for dt in (1e-6, 1.0):
        for size, density, kappa in ((1e-4, 1e-6, 1.0), (1e-4, 1e12, 1e16), (1e3, 1e12, 1e16),
                                     (1e3, 1e-6, 1.0)):
            d = hinge_dict(dt=dt)
            for b, x in zip(d['bodies'], (-1.5, 1.5)):
                b.update(box=[size] * 3, density=density, kappa=kappa, position=[x * size, 0, 0])
            d['joints'][0].update(p0=[0, 0, -size], p1=[0, 0, size])
            inertia = None
            for damping in (0.0, 1e9):                  # and the largest joint damping
                d['joints'][0]['damping'] = damping
                if inertia is not None and dt * damping > DAMPING_RATIO_MAX * inertia:
                    # dt d / I up to 4e34 here: one clear refusal naming the joint
                    with pytest.raises(SceneError, match=r"joint 'hinge': damping 1e\+09 N m s/rad "
                                                         r"is .* lock it, or lower the damping"):
                        World(Scene.from_dict(d))
                    continue
                world = World(Scene.from_dict(d))
                inertia = world.solver.axis_inertia(0)
                for _ in range(2):
                    world.step()
                assert np.all(np.isfinite(world.joint_angles()))


@pytest.mark.parametrize('dt, words', [
    (-1.0, 'must be > 0, got -1.0'), (0, 'must be > 0, got 0'), (float('nan'), 'must be finite, got nan'),
    (1e-300, '1e-300 is outside the supported range 1e-06 to 1 s'), (1000.0, 'outside the supported range'),
    (10 ** 400, 'an integer of 401 digits'), ('0.01', "must be a number, got '0.01'"), ([0.01], 'must be a number'),
])
def test_world_dt_argument_is_checked_as_the_scenes_dt(dt, words):
    """World(scene, dt) overrides the scene's dt and gets the scene's checks
    (unchecked, dt = -1 would run backwards in time, 1e3 s would run, 0 would fall back to
    the scene's dt)."""
    from abd_joint_sim import World
    with pytest.raises(SceneError) as err:
        World(Scene.from_dict(hinge_dict()), dt=dt)
    assert str(err.value).startswith('dt argument: ') and words in str(err.value), str(err.value)


def test_world_dt_argument_takes_numbers_and_a_model_keeps_its_own():
    from abd_joint_sim import World
    scene = Scene.from_dict(hinge_dict())
    assert World(scene, dt=0.002).dt == 0.002 and World(scene, dt=np.float32(0.5)).dt == 0.5
    assert World(scene).dt == scene.dt
    model = compile_scene(scene, 0.004)
    assert World(model).dt == 0.004 and World(model, dt=0.004).dt == 0.004
    with pytest.raises(ValueError, match=r'dt=0.002 given with a compiled Model of dt 0.004'):
        World(model, dt=0.002)
