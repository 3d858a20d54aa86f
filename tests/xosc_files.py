"""Small OpenSCENARIO files for the importer's tests (tests/test_xosc_import.py) and the bad-input corpus
(tests/bad_inputs/xosc/, written by `python tests/xosc_files.py`): a straight road of two 3.5 m lanes along +y,
an ego car on it, and what each test puts beside it."""

from __future__ import annotations

import sys
from pathlib import Path

ROAD = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="7" name="straight"/>
<road id="7" length="200" junction="-1"><planView><geometry s="0" x="100" y="-50" hdg="1.5707963267948966"
length="200"><line/></geometry></planView><lanes><laneSection s="0">
<left><lane id="1" type="driving" level="false"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></left>
<center><lane id="0" type="none" level="false"/></center>
<right><lane id="-1" type="driving" level="false"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right>
</laneSection></lanes></road></OpenDRIVE>
"""

AXLES = ('<Performance maxSpeed="50" maxAcceleration="5" maxDeceleration="10"/><Axles><FrontAxle maxSteering="0.5" '
         'wheelDiameter="0.6" trackWidth="1.5" positionX="2.8" positionZ="0.3"/><RearAxle maxSteering="0" '
         'wheelDiameter="0.6" trackWidth="1.5" positionX="0" positionZ="0.3"/></Axles>')


def vehicle(name: str, category: str = "car", length: float = 4.4, height: float = 1.4, width: float = 1.8,
            controller: str = "") -> str:
    return (f'<ScenarioObject name="{name}"><Vehicle name="{name}_model" vehicleCategory="{category}"><BoundingBox>'
            f'<Center x="0" y="0" z="{height / 2}"/><Dimensions width="{width}" length="{length}" height="{height}"/>'
            f'</BoundingBox>{AXLES}<Properties/></Vehicle>{controller}</ScenarioObject>')


def pedestrian(name: str, height: float = 1.8) -> str:
    return (f'<ScenarioObject name="{name}"><Pedestrian name="{name}_model" pedestrianCategory="pedestrian" mass="70">'
            f'<BoundingBox><Center x="0" y="0" z="{height / 2}"/><Dimensions width="0.5" length="0.4" '
            f'height="{height}"/></BoundingBox><Properties/></Pedestrian></ScenarioObject>')


CONTROLLER = ('<ObjectController><Controller name="DriverModel"><Properties><Property name="mode" value="override"/>'
              '</Properties></Controller></ObjectController>')


def lane(s, offset=0.0, heading: float | None = None) -> str:
    turn = f'<Orientation type="relative" h="{heading}"/>' if heading is not None else ""
    return f'<Position><LanePosition roadId="7" laneId="-1" s="{s}" offset="{offset}">{turn}</LanePosition></Position>'


def teleport(s, offset=0.0, heading: float | None = None) -> str:
    return f"<PrivateAction><TeleportAction>{lane(s, offset, heading)}</TeleportAction></PrivateAction>"


def speed(value) -> str:
    return ('<PrivateAction><LongitudinalAction><SpeedAction><SpeedActionDynamics dynamicsShape="step" value="0" '
            f'dynamicsDimension="time"/><SpeedActionTarget><AbsoluteTargetSpeed value="{value}"/></SpeedActionTarget>'
            '</SpeedAction></LongitudinalAction></PrivateAction>')


def polyline(vertices: list[tuple[float, float]], times: list[float] | None = None) -> str:
    """A FollowTrajectoryAction over lane positions (s, offset); with `times`, timed (TimeReference Timing)."""
    marks = [f' time="{t}"' for t in times] if times else [""] * len(vertices)
    shape = "".join(f"<Vertex{m}>{lane(s, o)}</Vertex>" for (s, o), m in zip(vertices, marks))
    timing = ('<Timing domainAbsoluteRelative="relative" scale="1.0" offset="0.0"/>' if times else "<None/>")
    return ('<PrivateAction><RoutingAction><FollowTrajectoryAction><TrajectoryRef><Trajectory name="walk" '
            f'closed="false"><Shape><Polyline>{shape}</Polyline></Shape></Trajectory></TrajectoryRef>'
            f'<TimeReference>{timing}</TimeReference><TrajectoryFollowingMode followingMode="position"/>'
            '</FollowTrajectoryAction></RoutingAction></PrivateAction>')


def event(actor: str, action: str, at_time: float = 0.0) -> str:
    """A story whose one event gives `actor` the private action at a simulation time."""
    return (f'<Story name="s"><Act name="a"><ManeuverGroup name="g" maximumExecutionCount="1"><Actors '
            f'selectTriggeringEntities="false"><EntityRef entityRef="{actor}"/></Actors><Maneuver name="m"><Event '
            f'name="go" priority="override"><Action name="act">{action}</Action><StartTrigger><ConditionGroup>'
            f'<Condition name="c" delay="0" conditionEdge="rising"><ByValueCondition><SimulationTimeCondition '
            f'value="{at_time}" rule="greaterThan"/></ByValueCondition></Condition></ConditionGroup></StartTrigger>'
            '</Event></Maneuver></ManeuverGroup><StartTrigger><ConditionGroup><Condition name="t" delay="0" '
            'conditionEdge="none"><ByValueCondition><SimulationTimeCondition value="0" rule="greaterThan"/>'
            '</ByValueCondition></Condition></ConditionGroup></StartTrigger></Act></Story>')


def scenario(entities: str, init: dict[str, str], story: str = "", params: dict[str, str] | None = None) -> str:
    """A scenario on ROAD (saved beside it as road.xodr): entities, each entity's Init actions, a story."""
    declared = "".join(f'<ParameterDeclaration name="{k}" parameterType="double" value="{v}"/>'
                       for k, v in (params or {}).items())
    privates = "".join(f'<Private entityRef="{n}">{a}</Private>' for n, a in init.items())
    story = story or ('<Story name="s"><Act name="a"><ManeuverGroup name="g" maximumExecutionCount="1"><Actors '
                      'selectTriggeringEntities="false"/></ManeuverGroup><StartTrigger/></Act></Story>')
    return ('<?xml version="1.0"?>\n<OpenSCENARIO><FileHeader revMajor="1" revMinor="2" date="2026-01-01T00:00:00" '
            f'description="a test" author="t"/><ParameterDeclarations>{declared}</ParameterDeclarations>'
            '<CatalogLocations/><RoadNetwork><LogicFile filepath="road.xodr"/></RoadNetwork>'
            f'<Entities>{entities}</Entities><Storyboard><Init><Actions>{privates}</Actions></Init>{story}'
            '<StopTrigger/></Storyboard></OpenSCENARIO>\n')


def write(folder: Path, name: str, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "road.xodr").write_text(ROAD)
    path = folder / name
    path.write_text(text)
    return path


EGO = {"Ego": teleport(20) + speed(2.5)}
PERSON = {"Walker": teleport(40, -3.0, 1.5707963267948966)}

# the bad-input corpus' files: each refused in one line (tests/bad_inputs/cases.yaml, `scenario.import-*`)
CORPUS = {
    "bicycle.xosc": scenario(vehicle("Ego") + vehicle("Cyclist", "bicycle", 1.8, 1.7, 0.6),
                             {**EGO, "Cyclist": teleport(40, -1.0)}),
    "motorbike.xosc": scenario(vehicle("Ego") + vehicle("Rider", "motorbike", 2.2, 1.5, 0.8),
                               {**EGO, "Rider": teleport(40, -1.0)}),
    "overflow.xosc": scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, **PERSON},
                              params={"Far": "${10.0**400}"}),
    "unknown_function.xosc": scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, **PERSON},
                                      params={"Odd": "${log(2)}"}),
    "no_target.xosc": scenario(vehicle("Ego") + vehicle("Parked", length=4.6), {**EGO, "Parked": teleport(40, 2.0)}),
    # a file that imports as it is: its entry gives a --param it does not declare (issue 47, item 4)
    "one_parameter.xosc": scenario(vehicle("Ego") + pedestrian("Walker"), {**EGO, **PERSON},
                                   params={"WalkerS": "40"}),
}

if __name__ == "__main__":
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent / "bad_inputs" / "xosc"
    for name, text in CORPUS.items():
        write(out, name, text)
