"""The session stream's protocol, shared by the server and the workers (docs/design/conventions.md, streaming protocol); the one
worker package the server imports for sessions.

state.py     SessionState (what is stored per session), new_state, restore_state
messages.py  the client messages, their policy (storage, urgent, drags, readonly_ok) and ``apply``
effects.py   what a message or worker event asks for beyond its state: one dataclass per kind
events.py    server → client events, worker → server events and ``apply_event``
wire.py      binary frames, the stream's JSON Schema, the size and depth checks of a message
"""
from .effects import (MAX_REGION_STEPS, NO_EFFECT, Convert, Effect, FitPaint, Pick, SelectObject, Moved, NewMaterial, NoEffect,  # noqa: F401
                      RecordStroke, Redo, Refit, RegionsChanged, RejectStroke, Relight, Save, StoreEffect, StoreSave, SwitchRenderer,
                      Undo)
from .events import (WORKER_EVENTS, ConvertedEvent, CurveEvent, ErrorEvent, ExposureEvent, FitEvent, FitStats,  # noqa: F401
                     GuidanceEvent, HelloEvent, NoteEvent, ObjectEvent, PaintEvent, PeerEvent, PickedEvent, RendererEvent, SavedEvent,
                     SaveRequest, ServerEvent, StrokeEvent, apply_event,
                     server_event, worker_event)
from .messages import (_MESSAGES, AnyClientMsg, ClientMsg, ConvertMsg, DisplayMsg, ObjectMsg, PickMsg, EnvironmentMsg, FitMsg, LightMsg,  # noqa: F401
                       MaterialMsg, MoveMsg, PaintMsg, RedoMsg, RegionMsg, RendererMsg, SaveMsg, Storage, StrokeMsg, UndoMsg,
                       VariantMsg, ViewMsg, apply, client_msg, message)
from .state import (EnvPreset, ObjectEdit, PendingSave, SessionState, StateError, Tone, Variant, copy_state,  # noqa: F401
                    new_state, restore_state)
from .wire import (BadMessage, FrameHeader, decode_frame, encode_frame, json_depth,  # noqa: F401
                   parse_message_text, stream_schema)
