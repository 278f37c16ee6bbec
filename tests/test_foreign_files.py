"""Packings made by other codes: a LAMMPS packing (dump custom + dump local of pair/local, made by
LAMMPS itself: tests/data/lammps) and the same packing as extended XYZ, analysed by GranLab."""

import json
from pathlib import Path

import numpy as np
import pytest

from granlab.engine.analysis import stiffness as st
from granlab.engine.analysis.packing import packing_stats
from granlab.engine.analysis.rigidity import rigidity, rigidity_matrix, self_stress_states
from granlab.engine.analysis.states import read_state
from granlab.engine.io.lammps import Dump
from tests.test_cli import granlab

DATA = Path(__file__).parent / "data" / "lammps"
PACKING, CONTACTS, XYZ = DATA / "packing.dump", DATA / "contacts.dump", DATA / "packing.xyz"


def brute_force_contacts(state):
    """Touching pairs by a loop over every pair and its nearest periodic image."""
    n, lengths = state.disks, state.box_lengths
    pairs = []
    for a in range(n):
        for b in range(a + 1, n):
            delta = state.positions[a] - state.positions[b]
            for axis in range(2):
                if state.periodic[axis]:
                    delta[axis] -= lengths[axis] * round(delta[axis] / lengths[axis])
            if np.hypot(*delta) <= state.radii[a] + state.radii[b] + 1e-6 * 2.0 * state.radii.mean():
                pairs.append((a, b))
    return pairs


def brute_force_rigidity(state):
    """(N_f, M, K, H) of the frictional contacts from a dense rigidity matrix: a normal and a
    tangential relative velocity per contact, 3 velocity components per disk, rank by SVD."""
    n, c = state.disks, state.contacts
    rows = []
    for i, j, image in zip(c.i, c.j, c.image):
        branch = state.positions[i] - state.positions[j] - image * state.box_lengths
        normal = branch / np.hypot(*branch)
        tangent = np.array([-normal[1], normal[0]])
        row_n, row_t = np.zeros(3 * n), np.zeros(3 * n)
        row_n[3 * i:3 * i + 2], row_n[3 * j:3 * j + 2] = normal, -normal
        row_t[3 * i:3 * i + 2], row_t[3 * j:3 * j + 2] = tangent, -tangent
        row_t[3 * i + 2], row_t[3 * j + 2] = -state.radii[i], -state.radii[j]
        rows += [row_n, row_t]
    g = np.array(rows)
    rank = np.linalg.matrix_rank(g)
    return 3 * n, g.shape[0], 3 * n - rank, g.shape[0] - rank


def test_the_lammps_packing_with_its_contacts_agrees_with_the_packing_rebuilt_from_positions():
    with_forces = read_state(PACKING, contacts=CONTACTS)
    geometric = read_state(PACKING)
    assert with_forces.forces_known and not geometric.forces_known
    assert with_forces.disks == geometric.disks == 200 and with_forces.periodic == (True, True)
    pairs = {(int(i), int(j)) for i, j in zip(with_forces.contacts.i, with_forces.contacts.j)}
    assert pairs == {(int(i), int(j)) for i, j in zip(geometric.contacts.i, geometric.contacts.j)}
    assert pairs == set(brute_force_contacts(geometric))
    assert np.all(with_forces.contacts.normal_force > 0) and np.all(with_forces.contacts.surface_gap < 0)
    stats, stats_geometric = packing_stats(with_forces), packing_stats(geometric)
    brute_phi = np.pi * np.sum(geometric.radii ** 2) / np.prod(geometric.box_lengths)
    assert stats.phi == stats_geometric.phi == pytest.approx(brute_phi, rel=1e-12)
    assert stats.z == stats_geometric.z == 2.0 * len(pairs) / 200
    touching = np.bincount(np.array(sorted(pairs)).ravel(), minlength=200)
    assert stats.rattlers == stats_geometric.rattlers == np.count_nonzero(touching == 0)
    for state in (with_forces, geometric):
        counts = rigidity(st.network(state))
        assert (counts.degrees_of_freedom, counts.constraints, counts.floppy_modes, counts.hyperstaticity) == \
            brute_force_rigidity(state)
        # H as packings of more than 1500 constraints get it: the inertia of [[-I, G^T], [G, -t I]]
        assert self_stress_states(rigidity_matrix(st.network(state)), dense_size=0) == counts.hyperstaticity


def test_the_forces_read_from_pair_local_balance_on_every_disk():
    """Static packing: on every disk with contacts, the LAMMPS contact forces (normal and tangential,
    split by GranLab on n and t) add up to zero, and so do their moments, to the dump's precision."""
    state = read_state(PACKING, contacts=CONTACTS)
    c, n = state.contacts, state.disks
    branch = state.positions[c.i] - state.positions[c.j] - c.image * state.box_lengths
    normal = branch / np.hypot(branch[:, 0], branch[:, 1])[:, None]
    tangent = np.column_stack([-normal[:, 1], normal[:, 0]])
    force = c.normal_force[:, None] * normal + c.tangential_force[:, None] * tangent
    net = np.zeros((n, 2))
    np.add.at(net, c.i, force)
    np.add.at(net, c.j, -force)
    moment = np.zeros(n)
    np.add.at(moment, c.i, -state.radii[c.i] * c.tangential_force)
    np.add.at(moment, c.j, -state.radii[c.j] * c.tangential_force)
    carrying = np.bincount(np.concatenate([c.i, c.j]), minlength=n) > 0
    scale = float(np.mean(np.abs(c.normal_force)))
    assert np.abs(net[carrying]).max() < 1e-9 * scale
    assert np.abs(moment[carrying]).max() < 1e-9 * scale * state.radii.max()
    assert np.count_nonzero(c.tangential_force) > 0.9 * c.count  # friction carries load: the test can fail
    assert np.all(np.abs(c.tangential_force) <= 0.5 * c.normal_force * (1 + 1e-6))


def test_frames_are_picked_by_index_and_their_contacts_by_timestep():
    dump = Dump(PACKING)
    assert len(dump) == 3
    first = read_state(PACKING, frame=0, contacts=CONTACTS)
    assert first.step == dump.timesteps[0] and "frame 0" in first.source
    last = read_state(PACKING, frame=-1, contacts=CONTACTS)
    assert last.step == dump.timesteps[-1]
    assert first.contacts.count == last.contacts.count  # a static packing


def test_the_extended_xyz_of_the_same_packing_gives_the_same_packing():
    from_xyz, from_dump = read_state(XYZ), read_state(PACKING)
    assert from_xyz.periodic == (True, True)
    np.testing.assert_allclose(from_xyz.box_lengths, from_dump.box_lengths, rtol=1e-12)
    np.testing.assert_allclose(from_xyz.radii, from_dump.radii, rtol=1e-12)
    np.testing.assert_allclose(np.mod(from_xyz.positions - from_dump.positions + 1.0, from_dump.box_lengths) - 1.0,
                               0.0, atol=1e-9)
    assert packing_stats(from_xyz).z == packing_stats(from_dump).z


def test_granlab_analyze_reads_a_lammps_packing_with_its_contacts_and_law():
    result = json.loads(granlab("analyze", str(PACKING), "status", "--contacts", str(CONTACTS), "--mu", "0.5",
                                "--kn", "1000", "--kt", "285.714", "--json").stdout)
    assert result["forces_known"] and result["particles"] == 200
    assert result["law"] == {"friction": 0.5, "normal_stiffness": 1000.0, "tangential_stiffness": 285.714,
                             "assumed": []}
    assert result["agrees_with_dynamics"] is True
    text = granlab("analyze", str(PACKING), "packing", "--contacts", str(CONTACTS), "--mu", "0.5").stdout
    assert "timestep" in text and "Contact forces known" in text
    assert ("contact law assumed, the file carries none: K_n = 1000 (--kn), K_t = 1000 (--kt); given: mu = 0.5"
            in text)
    text = granlab("analyze", str(PACKING), "packing", "--contacts", str(CONTACTS), "--mu", "0.5", "--kn", "1000",
                   "--kt", "285.714").stdout
    assert "assumed" not in text  # was "contact law assumed" with all three given


def lines(path):
    return path.read_text().splitlines(keepends=True)


@pytest.fixture
def broken(tmp_path):
    """Files made from the fixtures with one thing wrong each."""
    dump, contacts = lines(PACKING), lines(CONTACTS)
    header = max(k for k, line in enumerate(dump) if line.startswith("ITEM: ATOMS"))  # of the last frame
    files = {}

    def write(name, text):
        files[name] = tmp_path / name
        files[name].write_text("".join(text))

    first_row = dump[header + 1].split()
    first_row[4] = "0.25"  # z of atom 1
    write("3d.dump", dump[:header + 1] + [" ".join(first_row) + "\n"] + dump[header + 2:])
    columns = dump[header].split()[2:]
    keep = [k for k, name in enumerate(columns) if name != "radius"]
    stripped = []
    for k, line in enumerate(dump):
        if line.startswith("ITEM: ATOMS"):
            stripped.append("ITEM: ATOMS " + " ".join(columns[m] for m in keep) + "\n")
        elif k > header and not line.startswith("ITEM") and len(line.split()) == len(columns):
            stripped.append(" ".join(line.split()[m] for m in keep) + "\n")
        else:
            stripped.append(line)
    write("no-radius.dump", stripped)
    write("truncated.dump", dump[:dump.index(dump[header]) + 50])
    write("cut-line.dump", dump[:-1] + [dump[-1][:20]])
    entry = max(k for k, line in enumerate(contacts) if line.startswith("ITEM: ENTRIES")) + 1
    unknown = contacts[entry].split()
    unknown[0] = "9999"
    write("unknown-id.dump", contacts[:entry] + [" ".join(unknown) + "\n"] + contacts[entry + 1:])
    write("other-timestep.dump", [line.replace(contacts[1], "77\n") if k == 1 else line
                                  for k, line in enumerate(contacts[:contacts.index("ITEM: TIMESTEP\n", 1)])])
    write("not-a-dump.txt", ["hello\n", "world\n"])
    write("no-lattice.xyz", ["2\n", "Properties=pos:R:3:radius:R:1\n", "0 0 0 0.5\n", "1 0 0 0.5\n"])
    write("no-radius.xyz", ["1\n", 'Lattice="5 0 0 0 5 0 0 0 1" pbc="T T F"\n', "X 0 0 0\n"])
    return files


def test_bad_files_get_one_line_naming_the_problem_and_exit_2(broken):
    packing, contacts = str(PACKING), str(CONTACTS)
    cases = [((str(broken["3d.dump"]), "packing"), "is a 3D packing: z spreads over 0.25"),
             ((str(broken["no-radius.dump"]), "packing"), "has no radius or diameter column"),
             ((str(broken["truncated.dump"]), "packing"), "is truncated: frame 0 (timestep"),
             ((str(broken["cut-line.dump"]), "packing"), "is truncated: its last line is cut short"),
             ((packing, "packing", "--contacts", str(broken["unknown-id.dump"])),
              "names atom ids the packing's frame does not hold: 9999"),
             ((packing, "packing", "--contacts", str(broken["other-timestep.dump"])),
              "has no contacts at timestep"),
             ((packing, "packing", "--contacts", packing), "this is a dump of atoms"),
             ((packing, "packing", "--contacts", contacts, "--contact-columns", "id1 id2 fx"),
              "--contact-columns names 3 columns"),
             ((packing, "packing", "--frame", "5"), "frame 5 is out of range"),
             ((packing, "packing", "--kn", "-1"), "normal_stiffness = -1.0 is not allowed"),
             ((str(broken["not-a-dump.txt"]), "packing"), "is neither an H5MD file, a LAMMPS text dump"),
             ((str(broken["no-lattice.xyz"]), "packing"), "Lattice"),
             ((str(broken["no-radius.xyz"]), "packing"), "has no radius or diameter column"),
             ((str(XYZ), "packing", "--contacts", contacts), "go with a LAMMPS dump")]
    for args, message in cases:
        process = granlab("analyze", *args, check=False)
        assert process.returncode == 2, (args, process.stderr)
        assert message in process.stderr, (args, process.stderr)
        assert process.stderr.count("\n") == 1 and "Traceback" not in process.stderr, (args, process.stderr)


def test_contact_columns_name_the_columns_of_an_unnamed_pair_local_dump(tmp_path):
    text = CONTACTS.read_text().replace("ITEM: ENTRIES id1 id2 dist fnx fny fnz fn ftx fty ftz",
                                        "ITEM: ENTRIES c_1[1] c_1[2] c_2[1] c_2[2] c_2[3] c_2[4] c_2[5] c_2[6] c_2[7] "
                                        "c_2[8]")
    unnamed = tmp_path / "unnamed.dump"
    unnamed.write_text(text)
    named = read_state(PACKING, contacts=CONTACTS)
    given = read_state(PACKING, contacts=unnamed, contact_columns=("id1", "id2", "-", "fx", "fy", "-", "-", "ftx",
                                                                   "fty", "-"))
    np.testing.assert_array_equal(named.contacts.tangential_force, given.contacts.tangential_force)
    with pytest.raises(Exception, match="has no id1, id2, fx, fy column"):
        read_state(PACKING, contacts=unnamed)


def test_a_file_that_reads_but_is_no_packing_is_said_so_with_its_likely_cause(tmp_path):
    """Each gave numbers without a word before: z = 0 (NaN z* in --json), phi = 46.6 and z = 121,
    disks 0.4 to 1.4 mean forces out of balance."""
    header = next(line for line in lines(PACKING) if line.startswith("ITEM: ATOMS"))
    names = header.split()[2:]
    x, radius = names.index("x"), names.index("radius")

    def swapped(line):
        words = line.split()
        if len(words) != len(names) or line.startswith("ITEM"):
            return line
        words[x], words[radius] = words[radius], words[x]
        return " ".join(words) + "\n"

    diameter, swap, normal_only = tmp_path / "diameter.dump", tmp_path / "swap.dump", tmp_path / "normal.dump"
    diameter.write_text("".join(lines(PACKING)).replace(" radius ", " diameter "))
    swap.write_text("".join(swapped(line) for line in lines(PACKING)))
    local_names = next(line for line in lines(CONTACTS) if line.startswith("ITEM: ENTRIES")).split()[2:]
    keep = [k for k, name in enumerate(local_names) if name not in ("ftx", "fty", "ftz")]
    normal_only.write_text("".join(
        "ITEM: ENTRIES " + " ".join(local_names[k] for k in keep) + "\n" if line.startswith("ITEM: ENTRIES")
        else " ".join(line.split()[k] for k in keep) + "\n" if len(line.split()) == len(local_names) else line
        for line in lines(CONTACTS)))
    cases = [((str(diameter),), "no two disks touch, so the coordination number means nothing: are the sizes radii "
                                "under a diameter's name"),
             ((str(swap),), "above 1: the disks are larger than their box; is another column read as the radius"),
             ((str(PACKING), "--contacts", str(normal_only)), "the contact forces do not balance: ")]
    for args, warning in cases:
        process = granlab("analyze", *args, "packing", "--json")
        assert warning in process.stderr and process.stderr.startswith("granlab analyze: warning: "), process.stderr
        assert json.loads(process.stdout)["warnings"]
    assert "dump the tangential ones too" in process.stderr
    for args in ((str(PACKING),), (str(XYZ),), (str(PACKING), "--contacts", str(CONTACTS))):
        process = granlab("analyze", *args, "packing", "--json")
        assert process.stderr == "" and json.loads(process.stdout)["warnings"] == []
