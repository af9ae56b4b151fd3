"""Release 0.4: precomputations of any renderer (kind, content-keyed parts); strokes a worker
rejected; sessions' client and last activity (limits, idle expiry); stored saves (idempotent).

Revision ID: 0002
Revises: 0001
"""
import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("precomputations") as b:
        b.add_column(sa.Column("kind", sa.String(16), nullable=False, server_default="cuts"))
        b.add_column(sa.Column("parts", sa.JSON, nullable=True))
    with op.batch_alter_table("strokes") as b:
        b.add_column(sa.Column("rejected", sa.Boolean, nullable=False, server_default=sa.false()))
    with op.batch_alter_table("sessions") as b:
        b.add_column(sa.Column("client", sa.String(64), nullable=False, server_default=""))
        b.add_column(sa.Column("last_active", sa.DateTime(timezone=True), nullable=True))
    op.create_table("session_saves",
                    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
                    sa.Column("session_id", sa.String(32), sa.ForeignKey("sessions.id"), nullable=False, index=True),
                    sa.Column("seq", sa.Integer, nullable=False),
                    sa.Column("design_id", sa.String(32), sa.ForeignKey("materials.id"), nullable=False),
                    sa.Column("version", sa.Integer, nullable=False),
                    sa.Column("created", sa.DateTime(timezone=True), nullable=False),
                    sa.UniqueConstraint("session_id", "seq"))


def downgrade() -> None:
    op.drop_table("session_saves")
    with op.batch_alter_table("sessions") as b:
        b.drop_column("last_active")
        b.drop_column("client")
    with op.batch_alter_table("strokes") as b:
        b.drop_column("rejected")
    with op.batch_alter_table("precomputations") as b:
        b.drop_column("parts")
        b.drop_column("kind")
