"""
A scenario run's result as people and CI servers read it.

One line per expectation (``report``), or a JUnit XML document (``junit_xml``) that
stays XML whatever the run's text held (``xml_safe``). ``scenario`` runs the
scenario; this only writes its result up.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

from sorter_cell.testing.scenario_types import ScenarioResult

_NOT_IN_XML = re.compile('[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff\ufffe\uffff]')


def xml_safe(text) -> str:
    r"""
    Return ``text`` with every character XML 1.0 cannot hold written as ``\xNN``.

    A name or a controller's stderr may hold ESC (colours), BEL or a NUL, which
    ElementTree writes as they are: the file is then no XML a CI server reads.
    """
    return _NOT_IN_XML.sub(lambda m: f'\\x{ord(m.group()):02x}', str(text))


def junit_xml(results: list, suite: str = 'sorter scenarios') -> str:
    """
    Return results as a JUnit XML document (one testcase per expectation).

    Parameters
    ----------
    results : list of ScenarioResult
        The runs.
    suite : str
        The test suite's name.

    Returns
    -------
    str
        The XML.

    """
    root = ET.Element('testsuites', name=suite)
    for r in results:
        failures = sum(not c.passed for c in r.checks) + bool(r.error)
        ts = ET.SubElement(
            root,
            'testsuite',
            name=r.name,
            tests=str(len(r.checks) + bool(r.error)),
            failures=str(failures),
            errors='0',
            time=f'{r.wall_s:.3f}',
        )
        if r.properties:
            props = ET.SubElement(ts, 'properties')
            for k, v in r.properties.items():
                ET.SubElement(props, 'property', name=str(k), value=str(v))
        if r.error:
            case = ET.SubElement(ts, 'testcase', classname=r.name, name='runs', time='0')
            ET.SubElement(case, 'failure', message=r.error).text = r.error + (
                f'\n{r.state}' if r.state else ''
            )
        for c in r.checks:
            case = ET.SubElement(ts, 'testcase', classname=r.name, name=c.text, time='0')
            if not c.passed:
                ET.SubElement(case, 'failure', message=c.detail.splitlines()[0]).text = (
                    c.detail
                    + (f'\n{r.state}' if r.state else '')
                    + (f'\nevidence: {r.record}' if r.record else '')
                )
        if r.record:
            ET.SubElement(ts, 'system-out').text = f'recording: {r.record}'
    for element in root.iter():  # names, messages, stderr: whatever the run's text held
        element.attrib = {k: xml_safe(v) for k, v in element.attrib.items()}
        if element.text:
            element.text = xml_safe(element.text)
    ET.indent(root)
    return ET.tostring(root, encoding='unicode', xml_declaration=True) + '\n'


def report(r: ScenarioResult) -> str:
    """
    Return a run's result as text: one line per expectation.

    Parameters
    ----------
    r : ScenarioResult
        The run.

    Returns
    -------
    str
        The lines.

    """
    lines = [
        f'scenario {r.name}: {"passed" if r.passed else "FAILED"} '
        f'({r.sim_s:.1f} s simulated in {r.wall_s:.1f} s)'
    ]
    if r.error:
        lines.append(f'  [error] {r.error}')
    lines += [f'  [slow] {note}' for note in r.notes]
    for c in r.checks:
        detail = c.detail.splitlines()[0] if c.detail else ''
        lines.append(f'  [{"ok" if c.passed else "FAIL"}] {c.text}: {detail}')
    if not r.passed and r.state:
        # where the run ended: the parcels, faults and PackML state behind the failure
        lines += ['  ' + x for x in r.state.splitlines()]
    elif r.record:
        lines.append(f'  recording: {r.record}')
    return '\n'.join(lines)
