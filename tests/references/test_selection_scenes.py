"""Tests of references/learned_single/fetch_selection_scenes.py on a tarball made here (no download)."""

from __future__ import annotations

import base64
import io
import tarfile

import pytest

from references.learned_single import fetch_selection_scenes as fetch


class TestSelectionScenes:
    def _package(self, payloads: dict) -> bytes:
        buffer = io.BytesIO()
        with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
            for name, data in payloads.items():
                text = f"export default 'data:application/exr;base64,{base64.b64encode(data).decode()}'\n".encode()
                info = tarfile.TarInfo(f"package/hdri/{name}.exr.js")
                info.size = len(text)
                tar.addfile(info, io.BytesIO(text))
        return buffer.getvalue()

    def test_decodes_the_embedded_exr_files(self) -> None:
        payloads = {name: b"\x76\x2f\x31\x01" + name.encode() * 3 for name in fetch.SCENES}
        payloads["hall"] = b"\x76\x2f\x31\x01hall"  # a training scene in the package: not taken
        assert fetch.scenes_from_package(self._package(payloads)) == {n: payloads[n] for n in fetch.SCENES}

    def test_refuses_what_is_not_exr(self) -> None:
        payloads = {name: b"\x76\x2f\x31\x01" for name in fetch.SCENES}
        payloads["night"] = b"GIF89a"
        with pytest.raises(ValueError, match="night"):
            fetch.scenes_from_package(self._package(payloads))

    def test_names_a_scene_missing_from_the_package(self) -> None:
        payloads = {name: b"\x76\x2f\x31\x01" for name in fetch.SCENES if name != "studio"}
        with pytest.raises(KeyError, match="studio"):
            fetch.scenes_from_package(self._package(payloads))
