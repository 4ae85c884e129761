"""tests/_ns_stack.py: the frames inspect.stack() gives, in its order, with the same function names, files and lines."""
import inspect

from _ns_stack import stack_without_sources


def _inner(get):
    return get()


def _outer(get):
    return _inner(get)


def test_same_frames_names_files_and_lines_as_inspect_stack():
    real, ours = _outer(lambda: inspect.stack()), _outer(lambda: stack_without_sources())  # one line: same linenos
    assert len(ours) == len(real) > 3
    assert [f.function for f in ours] == [f.function for f in real]  # what nerfstudio reads: stack()[2].function
    assert [(f.filename, f.lineno) for f in ours] == [(f.filename, f.lineno) for f in real]  # the same call line
    assert ours[2].function == "_outer" and all(f.code_context is None for f in ours)
