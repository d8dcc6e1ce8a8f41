"""What a calibration's verdict means for the user, in plain words, and what to do next.

The calibration's own message names the statistic that decided (for the expert and for the
record); :func:`plain_advice` turns its machine-readable reason (``diagnostics.refusal``, e.g.
``misfit_focal_length``; unchanged) or a COARSE / fine success into two short sentences: what it
means, what to do. The reason names themselves are kept as they are (scripts read them).
"""

from __future__ import annotations

from ..types import OWN_DETECTIONS

__all__ = ["plain_advice", "ADVICE", "OWN_DETECTIONS_ADVICE"]

_MORE = ("record (or pass) more frames in which objects stand at other places in the image and at other "
         "distances from the sensors, then run again")

#: reason code -> (what it means, what to do); a code not listed gets a general sentence.
ADVICE: dict[str, tuple[str, str]] = {
    "too_few_detections": ("the frames hold too few boxes (2D boxes in the images or 3D boxes in the clouds) "
                           "to fix a pose",
                           "check what the source carries (`xcalib validate SOURCE` counts the boxes of every "
                           "frame; docs/formats.md says where xcalib reads them), make them with `--detect` if it "
                           "has none, and use "
                           "frames with several vehicles or people seen by both sensors"),
    "collinear_3d": ("all objects lie along one line, which leaves a rotation about that line free",
                     "use frames in which objects also stand beside that line (other lanes, other places)"),
    "collinear_2d": ("all image boxes lie along one image line, which leaves a rotation free",
                     "use frames with objects in other parts of the image"),
    "few_places": ("too few objects were seen by both sensors in the same frame to fix a pose", _MORE),
    "few_matches_per_half": ("too few objects matched to check the pose on two halves of the frames", _MORE),
    "few_matches": ("too few image boxes could be paired with 3D boxes to check the pose", _MORE),
    "poorly_constrained": ("the objects seen do not pin the pose down: it could move noticeably and fit as well",
                           _MORE),
    "few_objects": ("the matches come from too few different objects (the same few objects seen again and "
                    "again) to check the pose", "use a longer stretch of the recording with more traffic"),
    "too_few_objects": ("the matches come from too few different objects for a trustworthy pose",
                        "use a longer stretch of the recording with more traffic"),
    "uncertain": ("the frames agree on a pose, but counting each object once it is too uncertain to deliver",
                  "use a longer stretch of the recording with more, and more varied, traffic"),
    "crowded": ("the frames are so crowded that image boxes cannot be told apart reliably",
                "use frames with less traffic, or a detector that separates overlapping objects"),
    "few_explained": ("the best pose explains only a few of the image boxes: the camera and the LiDAR may not "
                      "see the same scene, the detections may be poor, or the intrinsics may be wrong",
                      "open the overlays and the report; check that the camera is the one beside this LiDAR, "
                      "its intrinsics (`--intrinsics`) and the time alignment (`--tolerance`)"),
    "ambiguous": ("two quite different poses explain the boxes about equally well (a symmetric scene)",
                  "add frames with objects at other places so that one pose wins, or give a rough starting "
                  "pose with `--prior`"),
    "no_hypothesis": ("no starting pose was found: no three objects seen by both sensors fix one",
                      "check that the camera and the LiDAR look at the same place and that their times match "
                      "(`--tolerance`), or give a rough starting pose with `--prior`"),
    "mixed_cameras": ("the image boxes seem to come from more than one camera",
                      "calibrate each camera on its own (`--camera NAME`), with its own images and boxes"),
    "misfit_mixed_cameras": ("the image boxes seem to come from more than one camera, or some frames do not "
                             "belong to this camera",
                             "calibrate each camera on its own (`--camera NAME`) and check the frames' pairing"),
    "time_offset": ("the camera and the LiDAR seem out of time: moving objects sit shifted along their path",
                    "let xcalib estimate the offset (`--time-offset auto`), or fix the clocks' synchronisation"),
    "misfit_time_offset": ("the camera and the LiDAR seem out of time: moving objects sit shifted along their path",
                           "let xcalib estimate the offset (`--time-offset auto`), or fix the clocks' "
                           "synchronisation"),
    "misfit_box_frame": ("the 3D boxes do not stand on the ground of a z-up LiDAR frame: they may be given in "
                         "another frame (the camera's, or a y-up one)",
                         "give the 3D boxes in the LiDAR's own frame with z up (docs/formats.md)"),
    "selfcal": ("the camera's focal length or principal point could not be estimated as asked",
                "pass the camera's known intrinsics (`--intrinsics`), or `--refine-intrinsics none`"),
    "misfit_lens": ("the boxes fit a wider-angle (fisheye) lens than the pinhole one given",
                    "give the lens model in `--intrinsics` (docs/camera-models.md), or undistorted images"),
    "focal_unverifiable": ("these frames cannot check the given focal length, so a wrong one would go unnoticed",
                           "add frames with objects near and far and across the whole image; check that "
                           "`--intrinsics` is this camera's own file"),
    "principal_point_unverifiable": ("these frames cannot check the given image centre (principal point), so a "
                                     "wrong one would go unnoticed",
                                     "add frames with objects across the whole image; check that `--intrinsics` "
                                     "is this camera's own file"),
    "misfit_focal_length": ("the boxes fit a different focal length than the one given: the intrinsics are "
                            "probably wrong (another camera's file, or another image size)",
                            "check that `--intrinsics` is this camera's own file for this image size; if it is, "
                            "add frames with other objects at other places and depths and run again, and only "
                            "then let xcalib estimate the focal length (`--refine-intrinsics focal`)"),
    "misfit_principal_point": ("the boxes fit a different image centre (principal point) than the one given: "
                               "the intrinsics are probably wrong (e.g. for a cropped image)",
                               "check that `--intrinsics` is this camera's own file for this image size; if it "
                               "is, add frames with objects across the whole image, and only then let xcalib "
                               "estimate it (`--refine-intrinsics focal+center`)"),
    "misfit_mirrored": ("the boxes fit a left-right mirrored image much better: the image (or the LiDAR's "
                        "axes) is probably flipped",
                        "check that the images are not mirrored and that the LiDAR frame is right-handed, z up"),
}


#: a focal length / image centre misfit when the boxes are xcalib's own (``calibrate --detect``, or a
#: bag ``xcalib detect`` wrote; the result's ``boxes_source`` says so): the boxes, not
#: the intrinsics, are the likely cause, and changing the intrinsics would fit the pose to them
OWN_DETECTIONS_ADVICE: dict[str, tuple[str, str]] = {
    code: (f"the boxes fit a different {what} than the one given; these boxes come from xcalib's own label-free "
           "detectors, and there the boxes are the more likely cause than the intrinsics: a LiDAR box made "
           "without labels covers only the part of an object the LiDAR sees, so its size and centre differ from "
           "the object the camera's box outlines, and few distinct objects cannot tell such an error from a "
           f"wrong {what}",
           "keep the intrinsics if they are this camera's own (do not let xcalib estimate them from these "
           "boxes); calibrate with the 3D boxes of your perception stack (tracked, whole objects) if you have "
           "them (`xcalib validate SOURCE` shows what a source holds), or record longer, with moving traffic "
           "at many places and depths, and run again")
    for code, what in (("misfit_focal_length", "focal length"), ("misfit_principal_point", "image centre"))}


def plain_advice(result) -> list[str]:
    """Two or three plain lines for ``result`` (a :class:`CalibrationResult`): the verdict, what it
    means, what to do. The machine-readable reason is named in brackets for a refusal."""
    if result.success:
        checks = _checks_line(result)
        if not getattr(result, "coarse", False):
            return ["In short: a usable pose (fine): the files under ros/ can be used as they are."] + checks
        return ["In short: a rough pose (COARSE): good as a starting point, not precise enough to fuse the "
                "sensors' data."] + checks + [f"What to do: to make it fine, {_MORE}."]
    code = ""
    if result.diagnostics is not None:
        code = getattr(result.diagnostics, "refusal", "") or ""
    own = getattr(result, "boxes_source", "") == OWN_DETECTIONS  # boxes from xcalib's own detectors
    means, todo = (OWN_DETECTIONS_ADVICE if own and code in OWN_DETECTIONS_ADVICE else ADVICE).get(
        code, ("the frames do not determine the pose reliably, so none is reported", _MORE))
    return [f"In short: no pose was delivered ({code or 'refused'}): {means}.", f"What to do: {todo}."]


def _checks_line(result) -> list[str]:
    """One line on the misfit checks of a success: how many ran, which (if any) flagged."""
    d = result.diagnostics
    checks = list(getattr(d, "misfit", None) or []) if d is not None else []
    if not checks:
        return []
    flagged = [c.name for c in checks if c.flagged]
    if not flagged:
        return [f"Checks: the {len(checks)} checks for a model misfit (wrong focal length or image centre, a "
                "mirrored image, mixed cameras, sensors out of time, a second pose, ...) found nothing wrong."]
    return [f"Checks: {len(flagged)} of {len(checks)} checks for a model misfit flagged ({', '.join(flagged)}): "
            "read their lines above (summary.txt) before using the pose."]
