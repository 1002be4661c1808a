"""``mi-plugins view``: the page of a saved solution (:meth:`mi_plugins.solution.solution.Solution.to_html`)."""
import os

import mitsuba as mi

from mi_plugins.solution.solution import Solution


def view_files(solution_file, scene_file, output, sensor=0, exposure=0.0, defines=None):
    """``mi-plugins view``: the page of the solution saved in ``solution_file`` for the scene
    of ``scene_file`` (XML, with ``defines`` for its $parameters), written to ``output``."""
    if not str(output).lower().endswith((".html", ".htm")):
        raise ValueError("-o %s: the page's name must end in .html or .htm" % output)
    for kind, path in (("solution", solution_file), ("scene", scene_file)):
        if not os.path.isfile(path):
            raise FileNotFoundError("%s file '%s' does not exist" % (kind, path))
    scene = mi.load_file(scene_file, **(defines or {}))
    return Solution.load(solution_file, scene).to_html(output, scene, sensor, exposure)
